// neuras-three.js: the three.js loader of the NEURAS_neural_material glTF extension (neuras-distill's neural look).
//
//   import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
//   import { NeurasNeuralMaterial } from "./neuras-three.js";
//   const loader = new GLTFLoader().register((parser) => new NeurasNeuralMaterial(parser));
//   const gltf = await loader.loadAsync("scene.glb");
//   scene.add(gltf.scene);          // the neural mesh, and its skyboxes when the bundle has them
//
// One ES module, no build step; it imports "three" (an import map names it, as three.js's own examples do) and
// needs WebGL2 (THREE.WebGLRenderer). Tested with three 0.187 from npm. The extension is specified in
// neuras-distill's docs/formats.md ("The glTF neural material"); what this module does with it:
//
// * Each node that carries the extension keeps its glTF mesh (the plain texture) but hides it, and gets a child
//   THREE.Mesh drawn by the bundle's own shaders (THREE.RawShaderMaterial, GLSL ES 3.00, one material per draw
//   call): the extension's geometry (positions, uvs, shading normals, indices), its textures (integer and float
//   DataTextures, NEAREST, as the desktop player binds them) and the generated fragment shader with the MLP.
//   The mesh is an ordinary opaque three.js object: it is drawn with three.js's camera, writes depth and is
//   occluded by other objects; moving, rotating or scaling the node moves it (the view direction the MLP sees is
//   taken in the node's frame). A two-layer bundle's shell is drawn after the core where the core left the
//   stencil clear, so it needs a renderer made with { stencil: true }; without one the core is drawn alone.
// * The skyboxes (the extension's "sky") become a full-screen triangle at the far plane, drawn after every
//   opaque object where nothing wrote depth (renderOrder SKY_RENDER_ORDER), as the desktop player does.
// * Colour: the bundle's shaders compute display (sRGB-encoded) values. On the canvas with
//   renderer.outputColorSpace = SRGBColorSpace (three.js's default) they are written as they are; into a render
//   target or a linear output they are decoded to linear first, as three.js's own materials expect there.
//   Tone mapping is not applied (the values are what the field shows).
// * The soft-silhouette pass (the extension's "silhouette") works on the finished frame, so renderer.render does
//   not run it: NeurasSilhouettePass does, for a page that shows the bundle alone.
// * Bad input: an extension of a newer version, a buffer view or accessor beyond the file, or a shader that does
//   not compile: a console.error naming the problem, the plain-texture mesh stays visible, and
//   gltf.userData.neurasErrors lists the messages. The loaded parts are in gltf.userData.neuras
//   ({ meshes, skies, background }).
import * as THREE from "three";

export const NEURAL_EXTENSION = "NEURAS_neural_material";
export const NEURAL_EXTENSION_VERSION = 1;
export const SKY_RENDER_ORDER = 1e6;

const ARRAY_TYPES = { 5123: Uint16Array, 5125: Uint32Array, 5126: Float32Array };
const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };

// ------------------------------------------------------------------ reading the extension's data, checked
class Reader {
  constructor(json, bin) {
    this.json = json;
    this.bin = bin;      // the GLB's binary chunk (ArrayBuffer)
  }

  view(index, what) {
    const views = this.json.bufferViews || [];
    const v = views[index];
    if (!Number.isInteger(index) || !v) throw new Error(`${what}: buffer view ${index} does not exist`);
    const start = v.byteOffset || 0, size = v.byteLength;
    if (v.buffer !== 0 || !Number.isInteger(start) || !Number.isInteger(size) || start < 0 || size < 0 ||
        start + size > this.bin.byteLength) {
      throw new Error(`${what}: buffer view ${index} (${size} bytes at ${start}) lies beyond the file's ` +
                      `${this.bin.byteLength}-byte binary chunk: the file is truncated or damaged`);
    }
    return { start, size };
  }

  text(index, what) {
    const { start, size } = this.view(index, what);
    return new TextDecoder().decode(new Uint8Array(this.bin, start, size));
  }

  accessor(index, what, componentType, type) {
    const a = (this.json.accessors || [])[index];
    if (!Number.isInteger(index) || !a) throw new Error(`${what}: accessor ${index} does not exist`);
    if ((componentType && a.componentType !== componentType) || (type && a.type !== type) ||
        !ARRAY_TYPES[a.componentType] || !COMPONENTS[a.type]) {
      throw new Error(`${what}: accessor ${index} is ${a.componentType} ${a.type}, expected ${componentType} ${type}`);
    }
    const { start, size } = this.view(a.bufferView, what);
    const Type = ARRAY_TYPES[a.componentType], n = a.count * COMPONENTS[a.type], offset = a.byteOffset || 0;
    if (!Number.isInteger(a.count) || a.count < 0 || offset + n * Type.BYTES_PER_ELEMENT > size) {
      throw new Error(`${what}: accessor ${index} declares ${a.count} ${a.type} values, more than its buffer view holds`);
    }
    return new Type(this.bin.slice(start + offset, start + offset + n * Type.BYTES_PER_ELEMENT));
  }
}

// ------------------------------------------------------------------ shaders for three.js
// RawShaderMaterial with glslVersion GLSL3: three.js writes the #version line itself.
function withoutVersion(source, what) {
  const first = source.split("\n", 1)[0];
  if (!first.startsWith("#version 300 es")) throw new Error(`${what} is not GLSL ES 3.00 (first line ${first})`);
  return source.slice(first.length + 1);
}

// The bundle's fragment shaders write display values to `out vec4 f_color`; this wraps main() so the value is
// decoded to linear when three.js renders into a linear target. Alpha is 1 (an opaque object), except in
// NeurasSilhouettePass's target, which keeps the shaders' coverage (1 mesh, 0.302 shell, 0 sky) for the pass.
const OUTPUT_WRAP = `
uniform float neuras_linear_output;
uniform float neuras_coverage_alpha;
layout(location = 0) out highp vec4 neuras_fragment;
vec3 neurasLinear(vec3 c) {
    return mix(c / 12.92, pow((c + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), c));
}
void main() {
    neuras_main();
    vec3 c = clamp(f_color.rgb, 0.0, 1.0);
    neuras_fragment = vec4(neuras_linear_output > 0.5 ? neurasLinear(c) : c, neuras_coverage_alpha > 0.5 ? f_color.a : 1.0);
}
`;

function fragmentForThree(source, what) {
  let s = withoutVersion(source, what);
  const out = /\n\s*(layout\s*\([^)]*\)\s*)?out\s+vec4\s+f_color\s*;/;
  const main = /\bvoid\s+main\s*\(\s*\)/g;
  if (!out.test(s) || (s.match(main) || []).length !== 1) {
    throw new Error(`${what} does not declare 'out vec4 f_color' and one main(): not a neuras-distill shader`);
  }
  s = s.replace(out, "\nvec4 f_color;").replace(main, "void neuras_main()");
  return s + OUTPUT_WRAP;
}

// The output uniforms of a material for where three.js is drawing now (see OUTPUT_WRAP).
function setOutput(uniforms, renderer) {
  const target = renderer.getRenderTarget();
  uniforms.neuras_linear_output.value = linearOutput(renderer);
  uniforms.neuras_coverage_alpha.value = target !== null && target.texture.userData.neurasDisplay ? 1.0 : 0.0;
}

function linearOutput(renderer) {
  const target = renderer.getRenderTarget();
  if (target !== null && target.texture.userData.neurasDisplay) return 0.0;     // NeurasSilhouettePass's target
  const space = target === null ? renderer.outputColorSpace
    : (target.isXRRenderTarget === true ? target.texture.colorSpace : THREE.ColorManagement.workingColorSpace);
  return THREE.ColorManagement.getTransfer(space) === THREE.SRGBTransfer ? 0.0 : 1.0;
}

// ------------------------------------------------------------------ textures
function dataTexture(reader, desc) {
  const what = `texture ${desc.uniform}`;
  const a = (reader.json.accessors || [])[desc.accessor] || {};
  const integer = a.componentType === 5123;
  if (!integer && a.componentType !== 5126) throw new Error(`${what}: accessor ${desc.accessor} is neither uint16 nor float32`);
  let data = reader.accessor(desc.accessor, what);
  let comps = COMPONENTS[a.type];
  const layers = desc.layers || 1, w = desc.width, h = desc.height;
  if (!(Number.isInteger(w) && Number.isInteger(h) && Number.isInteger(layers)) || w * h * layers * comps !== data.length) {
    throw new Error(`${what}: ${w} x ${h} x ${layers} texels of ${comps} values do not match its ${data.length} values`);
  }
  if (!integer && comps === 3) {           // no RGB32F upload in three.js: pad to RGBA (the shaders read .rgb)
    const padded = new Float32Array(w * h * layers * 4);
    for (let i = 0; i < w * h * layers; i++) padded.set(data.subarray(3 * i, 3 * i + 3), 4 * i);
    data = padded;
    comps = 4;
  }
  const format = integer
    ? [THREE.RedIntegerFormat, THREE.RGIntegerFormat, THREE.RGBIntegerFormat, THREE.RGBAIntegerFormat][comps - 1]
    : [THREE.RedFormat, THREE.RGFormat, null, THREE.RGBAFormat][comps - 1];
  const type = integer ? THREE.UnsignedShortType : THREE.FloatType;
  const tex = layers > 1 ? new THREE.DataArrayTexture(data, w, h, layers) : new THREE.DataTexture(data, w, h);
  tex.format = format;
  tex.type = type;
  tex.internalFormat = (integer ? ["R16UI", "RG16UI", "RGB16UI", "RGBA16UI"] : ["R32F", "RG32F", "RGB32F", "RGBA32F"])[comps - 1];
  tex.minFilter = tex.magFilter = THREE.NearestFilter;
  tex.wrapS = tex.wrapT = THREE.ClampToEdgeWrapping;
  tex.generateMipmaps = false;
  tex.flipY = false;
  tex.unpackAlignment = 1;
  tex.colorSpace = THREE.NoColorSpace;
  tex.name = desc.uniform;
  tex.needsUpdate = true;
  return tex;
}

// ------------------------------------------------------------------ the neural mesh
const _inverse = new THREE.Matrix4(), _m = new THREE.Matrix4(), _v = new THREE.Vector3();

function neuralMesh(reader, ext, textures) {
  const g = ext.geometry || {};
  const geometry = new THREE.BufferGeometry();
  const position = new THREE.BufferAttribute(reader.accessor(g.POSITION, "geometry POSITION", 5126, "VEC3"), 3);
  geometry.setAttribute("position", position);           // three.js's bounds and frustum culling
  geometry.setAttribute("in_position", position);
  geometry.setAttribute("in_uv", new THREE.BufferAttribute(reader.accessor(g.TEXCOORD_0, "geometry TEXCOORD_0", 5126, "VEC2"), 2));
  geometry.setAttribute("in_normal", new THREE.BufferAttribute(reader.accessor(g.NORMAL, "geometry NORMAL", 5126, "VEC3"), 3));
  const indices = reader.accessor(g.indices, "geometry indices", 5125, "SCALAR");
  const vertices = position.count;
  for (let i = 0; i < indices.length; i++) {
    if (indices[i] >= vertices) throw new Error(`geometry indices: index ${indices[i]} beyond the ${vertices} vertices`);
  }
  geometry.setIndex(new THREE.BufferAttribute(indices, 1));
  geometry.computeBoundingSphere();
  geometry.computeBoundingBox();
  const vertexShader = withoutVersion(reader.text(ext.vertexShader, "vertex shader"), "the vertex shader");
  const programs = new Map();
  const calls = ext.drawCalls || [];
  if (!calls.length) throw new Error("the extension has no draw calls");
  const layered = calls.some((c) => c.layer >= 0);
  const meshes = [];
  for (const call of calls) {
    const faces = indices.length / 3;
    if (!Number.isInteger(call.firstFace) || !Number.isInteger(call.faceCount) || call.firstFace < 0 ||
        call.firstFace + call.faceCount > faces) {
      throw new Error(`draw call of layer ${call.layer}: faces ${call.firstFace}.. + ${call.faceCount} beyond the ${faces} faces`);
    }
    if (!programs.has(call.fragmentShader)) {
      programs.set(call.fragmentShader, fragmentForThree(reader.text(call.fragmentShader, `fragment shader of layer ${call.layer}`),
                                                         `the fragment shader of layer ${call.layer}`));
    }
    const uniforms = { u_mvp: { value: new THREE.Matrix4() }, u_cam_pos: { value: new THREE.Vector3() },
                       u_layer: { value: -1.0 }, neuras_linear_output: { value: 0.0 },
                       neuras_coverage_alpha: { value: 0.0 } };
    for (const [name, tex] of Object.entries(textures)) uniforms[name] = { value: tex };
    const material = new THREE.RawShaderMaterial({
      name: `neuras neural material (layer ${call.layer})`, glslVersion: THREE.GLSL3, uniforms,
      vertexShader, fragmentShader: programs.get(call.fragmentShader),
      side: ext.cullBackFaces ? THREE.FrontSide : THREE.DoubleSide,
    });
    const shell = layered && call.layer >= 1;
    if (layered) {                         // the core marks the stencil, the shell fills only what it left
      material.stencilWrite = true;
      material.stencilRef = 1;
      material.stencilFunc = shell ? THREE.NotEqualStencilFunc : THREE.AlwaysStencilFunc;
      material.stencilZPass = shell ? THREE.KeepStencilOp : THREE.ReplaceStencilOp;
    }
    const sub = new THREE.BufferGeometry();   // the same attributes and indices (one upload), its own range
    for (const [name, attribute] of Object.entries(geometry.attributes)) sub.setAttribute(name, attribute);
    sub.setIndex(geometry.index);
    sub.boundingSphere = geometry.boundingSphere;
    sub.boundingBox = geometry.boundingBox;
    sub.setDrawRange(3 * call.firstFace, 3 * call.faceCount);
    const mesh = new THREE.Mesh(sub, material);
    mesh.name = shell ? "neuras neural mesh (shell)" : "neuras neural mesh";
    mesh.renderOrder = shell ? 1 : 0;       // after the opaque objects of renderOrder 0: the core's stencil is set
    mesh.userData.neurasShell = shell;
    mesh.onBeforeRender = function (renderer, scene, camera) {
      if (shell && !renderer.getContext().getContextAttributes().stencil) {
        if (!neuralMesh.warned) console.warn("neuras-three: the renderer has no stencil buffer: the soft shell is not drawn (new THREE.WebGLRenderer({ stencil: true }))");
        neuralMesh.warned = true;
        material.uniforms.u_mvp.value.makeScale(0, 0, 0);  // every vertex at one point: nothing is drawn
        material.uniformsNeedUpdate = true;
        return;
      }
      _m.multiplyMatrices(camera.matrixWorldInverse, this.matrixWorld);
      material.uniforms.u_mvp.value.multiplyMatrices(camera.projectionMatrix, _m);
      _inverse.copy(this.matrixWorld).invert();
      material.uniforms.u_cam_pos.value.copy(_v.setFromMatrixPosition(camera.matrixWorld).applyMatrix4(_inverse));
      setOutput(material.uniforms, renderer);
      material.uniformsNeedUpdate = true;
    };
    meshes.push(mesh);
  }
  return meshes;
}

// ------------------------------------------------------------------ the skyboxes
function skyMesh(reader, ext, textures, origin) {
  const sky = ext.sky;
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(9), 3));   // unused: gl_VertexID
  const uniforms = { u_sky_origin: { value: new THREE.Vector3() }, u_cam_rot: { value: new THREE.Matrix3() },
                     u_intrinsics: { value: new THREE.Vector4() }, u_height: { value: 1.0 },
                     neuras_linear_output: { value: 0.0 }, neuras_coverage_alpha: { value: 0.0 } };
  for (const [name, tex] of Object.entries(textures)) uniforms[name] = { value: tex };
  const material = new THREE.RawShaderMaterial({
    name: "neuras skyboxes", glslVersion: THREE.GLSL3, uniforms,
    vertexShader: withoutVersion(reader.text(sky.vertexShader, "sky vertex shader"), "the sky vertex shader"),
    fragmentShader: fragmentForThree(reader.text(sky.fragmentShader, "sky fragment shader"), "the sky fragment shader"),
    depthWrite: false, depthFunc: THREE.LessEqualDepth, side: THREE.DoubleSide,
  });
  const c = sky.center;
  if (!Array.isArray(c) || c.length !== 3 || !c.every(Number.isFinite)) throw new Error("sky: center is not three numbers");
  const centre = new THREE.Vector3(c[0] - origin[0], c[1] - origin[1], c[2] - origin[2]);   // in the node's frame
  const mesh = new THREE.Mesh(geometry, material);
  mesh.name = "neuras skyboxes";
  mesh.frustumCulled = false;
  mesh.renderOrder = SKY_RENDER_ORDER;
  const viewport = new THREE.Vector4(), rot = new THREE.Matrix4(), x = new THREE.Vector3(), y = new THREE.Vector3(), z = new THREE.Vector3();
  mesh.onBeforeRender = function (renderer, scene, camera) {
    _inverse.copy(this.matrixWorld).invert();
    const u = material.uniforms;
    u.u_sky_origin.value.setFromMatrixPosition(camera.matrixWorld).applyMatrix4(_inverse).sub(centre);
    rot.multiplyMatrices(_inverse, camera.matrixWorld).extractBasis(x, y, z);
    x.normalize(); y.normalize(); z.normalize();
    u.u_cam_rot.value.set(x.x, y.x, z.x, x.y, y.y, z.y, x.z, y.z, z.z);
    renderer.getCurrentViewport(viewport);                 // physical pixels; gl_FragCoord counts from its corner
    const p = camera.projectionMatrix.elements;            // column-major: fx = P00 w/2, cx = (1 - P02) w/2, ...
    u.u_intrinsics.value.set(p[0] * viewport.z / 2, p[5] * viewport.w / 2,
                             (1 - p[8]) * viewport.z / 2 + viewport.x, (p[9] + 1) * viewport.w / 2);
    u.u_height.value = viewport.y + viewport.w;
    setOutput(u, renderer);
    material.uniformsNeedUpdate = true;
  };
  return mesh;
}

// ------------------------------------------------------------------ the silhouette pass (optional)
// The bundle's soft-silhouette pass, for a page that shows the bundle alone (as the desktop player does):
// pass.render(renderer, scene, camera) draws the scene into an RGBA8 target of display values with alpha
// cleared to 0 (coverage), then blends the pixels at coverage edges ([1 2 1] x [1 2 1] tent) into the current
// output. three.js's own materials write linear values into a target, so a scene with other objects should be
// drawn with renderer.render instead.
export class NeurasSilhouettePass {
  constructor(sources) {
    const [vertex, fragment] = sources;
    this.material = new THREE.RawShaderMaterial({
      name: "neuras silhouettes", glslVersion: THREE.GLSL3,
      uniforms: { u_scene: { value: null }, neuras_linear_output: { value: 0.0 }, neuras_coverage_alpha: { value: 0.0 } },
      vertexShader: withoutVersion(vertex, "the silhouette vertex shader"),
      fragmentShader: fragmentForThree(fragment, "the silhouette fragment shader"), depthTest: false, depthWrite: false,
    });
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(9), 3));
    this.quad = new THREE.Mesh(geometry, this.material);
    this.quad.frustumCulled = false;
    this.camera = new THREE.Camera();
    this.target = null;
  }

  render(renderer, scene, camera) {
    const size = renderer.getDrawingBufferSize(new THREE.Vector2());
    if (!this.target || this.target.width !== size.x || this.target.height !== size.y) {
      if (this.target) this.target.dispose();
      this.target = new THREE.WebGLRenderTarget(size.x, size.y, { depthBuffer: true, stencilBuffer: true,
                                                                  minFilter: THREE.LinearFilter, magFilter: THREE.LinearFilter });
      this.target.texture.userData.neurasDisplay = true;
    }
    const output = renderer.getRenderTarget(), autoClear = renderer.autoClear, rgb = {};
    renderer.setRenderTarget(this.target);
    renderer.getClearColor(new THREE.Color()).getRGB(rgb, THREE.SRGBColorSpace);   // display values, alpha 0
    renderer.state.buffers.color.setClear(rgb.r, rgb.g, rgb.b, 0, false);         // (not premultiplied)
    renderer.clear();
    renderer.autoClear = false;
    renderer.render(scene, camera);
    renderer.autoClear = autoClear;
    renderer.setRenderTarget(output);
    this.material.uniforms.u_scene.value = this.target.texture;
    setOutput(this.material.uniforms, renderer);
    this.material.uniformsNeedUpdate = true;
    renderer.render(this.quad, this.camera);
  }
}

// ------------------------------------------------------------------ the GLTFLoader plugin
export class NeurasNeuralMaterial {
  constructor(parser) {
    this.parser = parser;
    this.name = NEURAL_EXTENSION;
  }

  async afterRoot(result) {
    const json = this.parser.json;
    const found = (json.nodes || []).map((n, i) => [i, n.extensions && n.extensions[NEURAL_EXTENSION]]).filter(([, e]) => e);
    result.userData.neuras = { meshes: [], skies: [], silhouette: null, background: null };
    result.userData.neurasErrors = [];
    for (const [index, ext] of found) {
      try {
        const parts = await this.load(index, ext);
        const node = await this.parser.getDependency("node", index);
        hidePlain(node);
        for (const mesh of parts.meshes) node.add(mesh);
        if (parts.sky) node.add(parts.sky);
        const neuras = result.userData.neuras;
        neuras.meshes.push(...parts.meshes);
        if (parts.sky) neuras.skies.push(parts.sky);
        neuras.background = neuras.background || parts.background;
        neuras.silhouette = neuras.silhouette || parts.silhouette;
        node.userData.neuras = parts;
      } catch (err) {
        const msg = `neuras-three: node ${index}: ${err.message}; showing the plain texture instead`;
        console.error(msg);
        result.userData.neurasErrors.push(msg);
      }
    }
  }

  async load(index, ext) {
    if (typeof ext !== "object" || !Number.isInteger(ext.version)) throw new Error(`${NEURAL_EXTENSION} has no version`);
    if (ext.version > NEURAL_EXTENSION_VERSION) {
      throw new Error(`${NEURAL_EXTENSION} version ${ext.version} is newer than this plugin reads ` +
                      `(${NEURAL_EXTENSION_VERSION}): export it with this neuras-distill or use its neuras-three.js`);
    }
    const bin = await this.parser.getDependency("buffer", 0);
    const declared = ((this.parser.json.buffers || [])[0] || {}).byteLength;
    if (!(declared <= bin.byteLength)) throw new Error(`buffer 0 declares ${declared} bytes; the file holds ${bin.byteLength}: it is truncated`);
    const reader = new Reader(this.parser.json, bin);
    const textures = {};
    for (const desc of ext.textures || []) textures[desc.uniform] = dataTexture(reader, desc);
    const node = this.parser.json.nodes[index];
    const origin = node.translation || [0, 0, 0];
    const meshes = neuralMesh(reader, ext, textures);
    const sky = ext.sky ? skyMesh(reader, ext, textures, origin) : null;
    const silhouette = ext.silhouette ? [reader.text(ext.silhouette.vertexShader, "silhouette vertex shader"),
                                         reader.text(ext.silhouette.fragmentShader, "silhouette fragment shader")] : null;
    const bg = ext.background;
    return { meshes, sky, textures, silhouette,
             background: Array.isArray(bg) && bg.length === 3 ? new THREE.Color().setRGB(bg[0], bg[1], bg[2], THREE.SRGBColorSpace) : null };
  }
}

function hidePlain(node) {
  // the glTF mesh of the node: the node itself (one primitive) or its children (one per primitive); its
  // materials are made invisible so that the node's other children (the neural mesh) still draw
  const plain = node.isMesh ? [node] : node.children.filter((c) => c.isMesh);
  for (const mesh of plain) {
    for (const m of Array.isArray(mesh.material) ? mesh.material : [mesh.material]) m.visible = false;
  }
}
