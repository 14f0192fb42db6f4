// neuras-distill web player: plays a bundle exported by `neuras-distill export BUNDLE --format web --out DIR`.
//
// Plain WebGL2, no library, nothing fetched from outside this folder. It mirrors playback/renderer.py
// (BundleRenderer) pass for pass so a frame matches the desktop player's:
//   scene pass  into an RGBA8 texture + DEPTH_COMPONENT24 renderbuffer, cleared to (background, alpha 0), depth
//               test LESS, back faces culled when scene.cull_back_faces, one draw call per mesh layer
//               (scene.mesh.layers = rasterize.mesh_layers: [u_layer, first face, face count]) with the program
//               of that layer (shaders/mesh<L>.frag = shaders.shader_variant), u_mvp and u_cam_pos;
//   sky pass    (scene.sky) a full-screen triangle at the far plane, depth LEQUAL, no depth writes;
//   output      the scene is blitted to the canvas; with scene.silhouette the soft-silhouette pass
//               (playback/silhouette.py) then runs over the screen box of the mesh bounds, reading the scene
//               texture LINEAR filtered.
// Matrices are built in float64 (JS numbers) exactly as playback/projection.py builds them, camera values are
// float32 (Cameras.from_json), the camera is moved into the bundle frame (origin subtracted, rounded to float32
// like projection.shift_cameras), and only the final matrices are rounded to float32.
//
// Data: fetched over HTTP; from a file:// page (where fetch cannot read files) the same files come from data.js.
// URL: index.html?camera=N plays held-out camera N of cameras.json ("test") at its own size (default 0); &fit
// shows the canvas as wide as the page (the report's iframe); the frame keeps the camera's size.
// Drag to orbit (around the point of the view axis level with the mesh centre), wheel to zoom. The FPS counter
// shows frames drawn per second (requestAnimationFrame: capped by the display's refresh rate).
// window.neurasReady = true once the first frame is complete; window.neurasError = the message on failure;
// window.neurasTimeFrames(n) draws n frames back to back, each read back, and returns their times in ms
// (benchmarks/threejs_frame_time.py; the three.js page has the same hook).
// The binary files are little-endian; typed arrays read them as the platform's order (little-endian everywhere
// WebGL2 runs in practice).
"use strict";

(function () {
  const errorBox = document.getElementById("error");

  function fail(err) {
    const msg = String((err && err.message) || err);
    window.neurasError = msg;
    if (errorBox) errorBox.textContent = "neuras-distill player: " + msg;
    console.error(msg);
  }

  // ------------------------------------------------------------------ data: fetched, or data.js from file://
  // Over HTTP the files are fetched. A file:// page cannot fetch, so there the player loads data.js (written by
  // the export beside the files: window.NEURAS_WEB_DATA = {files: {path: base64}}) with a <script> tag, once.
  let embedded = null;
  function loadDataScript() {
    if (window.NEURAS_WEB_DATA) return Promise.resolve(window.NEURAS_WEB_DATA);
    return new Promise((resolve, reject) => {
      const s = document.createElement("script");
      s.src = "data.js";
      s.onload = () => (window.NEURAS_WEB_DATA ? resolve(window.NEURAS_WEB_DATA)
        : reject(new Error("data.js did not set window.NEURAS_WEB_DATA")));
      s.onerror = () => reject(new Error("data.js is missing: export again, or serve this folder (neuras-distill serve DIR)"));
      document.head.appendChild(s);
    });
  }
  async function embeddedBytes(path) {
    if (!embedded) embedded = loadDataScript();
    const b64 = (await embedded).files[path];
    if (b64 === undefined) throw new Error(`${path} is not in data.js`);
    const bin = atob(b64);
    const out = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) out[i] = bin.charCodeAt(i);
    return out.buffer;
  }
  const fromFile = window.location.protocol === "file:";
  async function fetchOk(path) {
    const r = await fetch(path);
    if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
    return r;
  }
  const getBytes = async (p) => (fromFile ? embeddedBytes(p) : (await fetchOk(p)).arrayBuffer());
  const getText = async (p) => (fromFile ? new TextDecoder().decode(await embeddedBytes(p)) : (await fetchOk(p)).text());
  const getJSON = async (p) => JSON.parse(await getText(p));

  // ------------------------------------------------------------------ maths (playback/projection.py)
  // Matrices are arrays of rows: m[r][c]; float64 throughout.
  function matmul(a, b) {
    const out = [];
    for (let r = 0; r < 4; r++) {
      out.push([0, 0, 0, 0]);
      for (let c = 0; c < 4; c++) {
        let s = 0;
        for (let k = 0; k < 4; k++) s += a[r][k] * b[k][c];
        out[r][c] = s;
      }
    }
    return out;
  }

  function viewMatrix(c2w) {              // world -> camera: [R^T, -R^T t]
    const out = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]];
    for (let i = 0; i < 3; i++) {
      let s = 0;
      for (let j = 0; j < 3; j++) {
        out[i][j] = c2w[j][i];
        s += c2w[j][i] * c2w[j][3];
      }
      out[i][3] = -s;
    }
    return out;
  }

  function projectionMatrix(fx, fy, cx, cy, w, h, near, far) {
    return [[2 * fx / w, 0, 1 - 2 * cx / w, 0],
            [0, 2 * fy / h, 2 * cy / h - 1, 0],
            [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
            [0, 0, -1, 0]];
  }

  function nearFar(bounds, c2w) {          // projection.near_far_for with the full pose
    const [b0, b1] = bounds;
    const c = [c2w[0][3], c2w[1][3], c2w[2][3]];
    const diag = Math.hypot(b1[0] - b0[0], b1[1] - b0[1], b1[2] - b0[2]);
    const absMax = (v) => Math.max(...v.map(Math.abs));
    const pad = 0.01 * diag + 1e-6 * Math.max(1.0, absMax([...b0, ...b1]), absMax(c));
    const lo = b0.map((x) => x - pad), hi = b1.map((x) => x + pad);
    const v = viewMatrix(c2w);
    let far = -Infinity, nearRaw = Infinity;
    for (const x of [lo[0], hi[0]]) for (const y of [lo[1], hi[1]]) for (const z of [lo[2], hi[2]]) {
      const depth = -(x * v[2][0] + y * v[2][1] + z * v[2][2] + v[2][3]);
      far = Math.max(far, depth);
      nearRaw = Math.min(nearRaw, depth);
    }
    if (!(far > 0)) far = Math.max(diag, 1.0);
    const near = Math.max(nearRaw, far * 1e-4);
    if (!(far > near)) far = near * 2.0;
    return [near, far];
  }

  function screenBox(bounds, mvp, w, h, margin = 2) {   // projection.screen_box: GL window rect (x, y, w, h)
    const xs = [], ys = [];
    for (const i of [0, 1]) for (const j of [0, 1]) for (const k of [0, 1]) {
      const p = [bounds[i][0], bounds[j][1], bounds[k][2], 1.0];
      const clip = mvp.map((row) => row[0] * p[0] + row[1] * p[1] + row[2] * p[2] + row[3] * p[3]);
      if (clip[3] <= 1e-9) return [0, 0, w, h];
      xs.push(clip[0] / clip[3]);
      ys.push(clip[1] / clip[3]);
    }
    let x0 = Math.floor((Math.min(...xs) + 1) * 0.5 * w) - margin;
    let x1 = Math.ceil((Math.max(...xs) + 1) * 0.5 * w) + margin;
    let y0 = Math.floor((Math.min(...ys) + 1) * 0.5 * h) - margin;
    let y1 = Math.ceil((Math.max(...ys) + 1) * 0.5 * h) + margin;
    x0 = Math.max(0, x0); y0 = Math.max(0, y0); x1 = Math.min(w, x1); y1 = Math.min(h, y1);
    return [x0, y0, Math.max(0, x1 - x0), Math.max(0, y1 - y0)];
  }

  const glMatrix = (m) => {               // column-major float32, as projection.gl_matrix
    const out = new Float32Array(16);
    for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) out[4 * c + r] = m[r][c];
    return out;
  };

  function camerasFrom(json) {            // Cameras.from_json: every value float32
    const f32 = Math.fround;
    return json.frames.map((f) => ({
      c2w: [0, 1, 2, 3].map((r) => (f.transform_matrix[r] || [0, 0, 0, 1]).map(f32)),
      fx: f32(f.fl_x), fy: f32(f.fl_y), cx: f32(f.cx), cy: f32(f.cy),
      width: Math.trunc(json.w), height: Math.trunc(json.h),
    }));
  }

  function shifted(c2w, origin) {         // projection.shift_cameras: centre - origin in float64, then float32
    if (!origin.some((x) => x !== 0)) return c2w;
    return c2w.map((row, r) => (r < 3 ? [row[0], row[1], row[2], Math.fround(row[3] - origin[r])] : row.slice()));
  }

  // ------------------------------------------------------------------ GL helpers
  function compile(gl, type, source, name) {
    const s = gl.createShader(type);
    gl.shaderSource(s, source);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) {
      throw new Error(`${name} does not compile: ${gl.getShaderInfoLog(s)}`);
    }
    return s;
  }

  function program(gl, vsSource, fsSource, name) {
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vsSource, name + " (vertex)"));
    gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fsSource, name + " (fragment)"));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`${name} does not link: ${gl.getProgramInfoLog(p)}`);
    const uniforms = {};
    const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; i++) {
      const info = gl.getActiveUniform(p, i);
      uniforms[info.name] = gl.getUniformLocation(p, info.name);
    }
    return { p, u: uniforms };
  }

  function texture(gl, desc, data) {
    const comps = desc.components;
    let internal, format, type, array;
    if (desc.type === "uint16") {
      internal = [gl.R16UI, gl.RG16UI, gl.RGB16UI, gl.RGBA16UI][comps - 1];
      format = [gl.RED_INTEGER, gl.RG_INTEGER, gl.RGB_INTEGER, gl.RGBA_INTEGER][comps - 1];
      type = gl.UNSIGNED_SHORT;
      array = new Uint16Array(data);
    } else {
      internal = [gl.R32F, gl.RG32F, gl.RGB32F, gl.RGBA32F][comps - 1];
      format = [gl.RED, gl.RG, gl.RGB, gl.RGBA][comps - 1];
      type = gl.FLOAT;
      array = new Float32Array(data);
    }
    if (array.length !== desc.width * desc.height * comps) {
      throw new Error(`${desc.file} holds ${array.length} values, expected ${desc.width * desc.height * comps}`);
    }
    const max = gl.getParameter(gl.MAX_TEXTURE_SIZE);   // the export keeps every side within scene.max_texture_size
    const layers = desc.layers || 1;         // an atlas in pages: a texture array, pages stacked along the rows
    const t = gl.createTexture();
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    let target = gl.TEXTURE_2D;
    if (layers > 1) {
      const maxLayers = gl.getParameter(gl.MAX_ARRAY_TEXTURE_LAYERS);
      if (desc.width > max || layers > maxLayers) {
        throw new Error(`the atlas has ${layers} pages of ${desc.width}x${desc.width} texels; this browser holds at most ` +
                        `${max}x${max} per page and ${maxLayers} pages: bake it again with texture.page_size ${Math.min(desc.width, max)} or less`);
      }
      target = gl.TEXTURE_2D_ARRAY;
      gl.bindTexture(target, t);
      gl.texImage3D(target, 0, internal, desc.width, desc.height / layers, layers, 0, format, type, array);
    } else {
      if (Math.max(desc.width, desc.height) > max) {
        throw new Error(`texture ${desc.name} is ${desc.width}x${desc.height}; this browser allows at most ${max} per side: ` +
                        `export it again with --max-texture-size ${max}`);
      }
      gl.bindTexture(target, t);
      gl.texImage2D(target, 0, internal, desc.width, desc.height, 0, format, type, array);
    }
    gl.texParameteri(target, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(target, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texParameteri(target, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(target, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    return { tex: t, target };
  }

  // ------------------------------------------------------------------ the player
  async function run() {
    const [scene, camerasJson] = await Promise.all([getJSON("scene.json"), getJSON("cameras.json")]);
    const params = new URLSearchParams(window.location.search);
    const camIndex = params.has("camera") ? Number(params.get("camera")) : 0;
    const cams = camerasFrom(camerasJson.test);
    if (!Number.isInteger(camIndex) || camIndex < 0 || camIndex >= cams.length) {
      throw new Error(`?camera=${params.get("camera")}: cameras.json has ${cams.length} held-out cameras (0..${cams.length - 1})`);
    }
    const canvas = document.getElementById("view");
    if (params.has("fit")) canvas.classList.add("fit");     // shown as wide as the page (pixels unchanged)
    const gl = canvas.getContext("webgl2", { antialias: false, alpha: false, depth: false, stencil: false,
                                             preserveDrawingBuffer: true, premultipliedAlpha: false });
    if (!gl) throw new Error("this browser has no WebGL2");

    // --- programs
    const sources = {};
    const wanted = [scene.vertex_shader, ...Object.values(scene.programs)];
    if (scene.sky) wanted.push(scene.sky.vertex, scene.sky.fragment);
    if (scene.silhouette) wanted.push(scene.silhouette.vertex, scene.silhouette.fragment);
    await Promise.all(wanted.map(async (p) => { sources[p] = await getText(p); }));
    const programs = {};
    for (const [layer, frag] of Object.entries(scene.programs)) {
      programs[layer] = program(gl, sources[scene.vertex_shader], sources[frag], frag);
    }
    const sky = scene.sky ? program(gl, sources[scene.sky.vertex], sources[scene.sky.fragment], scene.sky.fragment) : null;
    const blend = scene.silhouette
      ? program(gl, sources[scene.silhouette.vertex], sources[scene.silhouette.fragment], scene.silhouette.fragment) : null;

    // --- textures: unit = position in name order (as BundleRenderer binds them)
    const buffers = await Promise.all([scene.mesh.vbo, scene.mesh.ibo, ...scene.textures.map((t) => t.file)].map(getBytes));
    const textures = scene.textures.map((desc, unit) => ({ unit, name: desc.name, ...texture(gl, desc, buffers[2 + unit]) }));
    const sceneUnit = textures.length;          // the silhouette pass reads the scene colour here
    for (const prog of [...Object.values(programs), sky]) {
      if (!prog) continue;
      gl.useProgram(prog.p);
      for (const t of textures) if (prog.u[t.name]) gl.uniform1i(prog.u[t.name], t.unit);
    }

    // --- mesh: one VAO per program over the shared buffers (rasterize.mesh_vertex_array layout)
    const vbo = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, vbo);
    gl.bufferData(gl.ARRAY_BUFFER, buffers[0], gl.STATIC_DRAW);
    const ibo = gl.createBuffer();
    const vaos = {};
    for (const [layer, prog] of Object.entries(programs)) {
      const vao = gl.createVertexArray();
      gl.bindVertexArray(vao);
      gl.bindBuffer(gl.ARRAY_BUFFER, vbo);
      if (layer === Object.keys(programs)[0]) {
        gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
        gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, buffers[1], gl.STATIC_DRAW);
      } else {
        gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
      }
      for (const [name, size, offset] of [["in_position", 3, 0], ["in_uv", 2, 12], ["in_normal", 3, 20]]) {
        const loc = gl.getAttribLocation(prog.p, name);
        if (loc < 0) continue;
        gl.enableVertexAttribArray(loc);
        gl.vertexAttribPointer(loc, size, gl.FLOAT, false, 32, offset);
      }
      vaos[layer] = vao;
    }
    gl.bindVertexArray(null);
    const emptyVao = gl.createVertexArray();

    // --- framebuffers (per size)
    let target = null;
    function framebuffer(w, h) {
      if (target && target.w === w && target.h === h) return target;
      if (target) { gl.deleteFramebuffer(target.fbo); gl.deleteTexture(target.color); gl.deleteRenderbuffer(target.depth); }
      const color = gl.createTexture();
      gl.bindTexture(gl.TEXTURE_2D, color);
      gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA8, w, h);
      const filter = scene.silhouette ? gl.LINEAR : gl.NEAREST;   // LINEAR: 2 x 2 block means (silhouette.py)
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
      gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
      const depth = gl.createRenderbuffer();
      gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
      gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, w, h);
      const fbo = gl.createFramebuffer();
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
      gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, color, 0);
      gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
      const status = gl.checkFramebufferStatus(gl.FRAMEBUFFER);
      if (status !== gl.FRAMEBUFFER_COMPLETE) throw new Error(`scene framebuffer incomplete (0x${status.toString(16)})`);
      target = { w, h, fbo, color, depth };
      return target;
    }

    const origin = scene.origin, bounds = scene.bounds, bg = scene.background;

    function draw(cam) {                      // BundleRenderer._draw for one world camera
      const w = cam.width, h = cam.height;
      if (canvas.width !== w || canvas.height !== h) {
        canvas.width = w; canvas.height = h;
        canvas.style.width = w + "px"; canvas.style.height = h + "px";
      }
      const fb = framebuffer(w, h);
      gl.bindFramebuffer(gl.FRAMEBUFFER, fb.fbo);
      gl.viewport(0, 0, w, h);
      gl.disable(gl.SCISSOR_TEST);
      gl.depthMask(true);
      gl.clearColor(bg[0], bg[1], bg[2], 0.0);     // alpha 0: no mesh (the mesh shaders write 1)
      gl.clearDepth(1.0);
      gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
      for (const t of textures) { gl.activeTexture(gl.TEXTURE0 + t.unit); gl.bindTexture(t.target, t.tex); }
      gl.disable(gl.CULL_FACE); gl.disable(gl.BLEND);          // rasterize.set_raster_state
      gl.enable(gl.DEPTH_TEST);
      gl.depthFunc(gl.LESS);
      if (scene.cull_back_faces) { gl.frontFace(gl.CCW); gl.cullFace(gl.BACK); gl.enable(gl.CULL_FACE); }
      const local = shifted(cam.c2w, origin);
      const [near, far] = nearFar(bounds, local);
      const mvp = matmul(projectionMatrix(cam.fx, cam.fy, cam.cx, cam.cy, w, h, near, far), viewMatrix(local));
      if (scene.mesh.faces > 0) {
        const mvp32 = glMatrix(mvp);
        for (const prog of Object.values(programs)) {
          gl.useProgram(prog.p);
          if (prog.u.u_mvp) gl.uniformMatrix4fv(prog.u.u_mvp, false, mvp32);
          if (prog.u.u_cam_pos) gl.uniform3f(prog.u.u_cam_pos, local[0][3], local[1][3], local[2][3]);
        }
        for (const [layer, first, count] of scene.mesh.layers) {   // core first, then shell
          const key = String(Math.max(0, Math.trunc(layer)));
          const prog = programs[key];
          gl.useProgram(prog.p);
          if (prog.u.u_layer) gl.uniform1f(prog.u.u_layer, layer);
          gl.bindVertexArray(vaos[key]);
          gl.drawElements(gl.TRIANGLES, 3 * count, gl.UNSIGNED_INT, 12 * first);
        }
      }
      if (sky) {                                // after the mesh: only the pixels it left empty are shaded
        const c = scene.sky.center, m = cam.c2w;
        gl.useProgram(sky.p);
        if (sky.u.u_sky_origin) gl.uniform3f(sky.u.u_sky_origin, m[0][3] - c[0], m[1][3] - c[1], m[2][3] - c[2]);
        if (sky.u.u_cam_rot) {
          gl.uniformMatrix3fv(sky.u.u_cam_rot, false,
                              new Float32Array([m[0][0], m[1][0], m[2][0], m[0][1], m[1][1], m[2][1], m[0][2], m[1][2], m[2][2]]));
        }
        if (sky.u.u_intrinsics) gl.uniform4f(sky.u.u_intrinsics, cam.fx, cam.fy, cam.cx, cam.cy);
        if (sky.u.u_height) gl.uniform1f(sky.u.u_height, h);
        gl.disable(gl.CULL_FACE);
        gl.enable(gl.DEPTH_TEST);
        gl.depthFunc(gl.LEQUAL);
        gl.depthMask(false);
        gl.bindVertexArray(emptyVao);
        gl.drawArrays(gl.TRIANGLES, 0, 3);
        gl.depthMask(true);
      }
      gl.bindVertexArray(null);
      gl.bindFramebuffer(gl.READ_FRAMEBUFFER, fb.fbo);
      gl.bindFramebuffer(gl.DRAW_FRAMEBUFFER, null);
      gl.blitFramebuffer(0, 0, w, h, 0, 0, w, h, gl.COLOR_BUFFER_BIT, gl.NEAREST);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      if (blend) {                              // BundleRenderer._blend_silhouettes
        const box = screenBox(bounds, mvp, w, h);
        if (box[2] > 0 && box[3] > 0) {
          gl.disable(gl.DEPTH_TEST); gl.disable(gl.CULL_FACE);
          gl.enable(gl.SCISSOR_TEST);
          gl.scissor(box[0], box[1], box[2], box[3]);
          gl.activeTexture(gl.TEXTURE0 + sceneUnit);
          gl.bindTexture(gl.TEXTURE_2D, fb.color);
          gl.useProgram(blend.p);
          gl.uniform1i(blend.u.u_scene, sceneUnit);
          gl.bindVertexArray(emptyVao);
          gl.drawArrays(gl.TRIANGLES, 0, 3);
          gl.bindVertexArray(null);
          gl.disable(gl.SCISSOR_TEST);
          gl.bindTexture(gl.TEXTURE_2D, null);   // not bound while the next scene pass renders into it
        }
      }
    }

    // --- orbit controls (world frame, float64)
    const cam = JSON.parse(JSON.stringify(cams[camIndex]));
    const centre = [0, 1, 2].map((k) => 0.5 * (bounds[0][k] + bounds[1][k]) + origin[k]);
    const pos = () => [cam.c2w[0][3], cam.c2w[1][3], cam.c2w[2][3]];
    const col = (k) => [cam.c2w[0][k], cam.c2w[1][k], cam.c2w[2][k]];
    const fwd = col(2).map((x) => -x);
    const ahead = fwd.reduce((s, f, k) => s + f * (centre[k] - pos()[k]), 0);
    const pivot = ahead > 0 ? pos().map((p, k) => p + ahead * fwd[k]) : centre;
    const upAxis = col(1);
    function rotate(axis, angle) {               // rotate the camera about `axis` through the pivot (Rodrigues)
      const n = Math.hypot(...axis), [x, y, z] = axis.map((a) => a / n), c = Math.cos(angle), s = Math.sin(angle);
      const R = [[c + x * x * (1 - c), x * y * (1 - c) - z * s, x * z * (1 - c) + y * s],
                 [y * x * (1 - c) + z * s, c + y * y * (1 - c), y * z * (1 - c) - x * s],
                 [z * x * (1 - c) - y * s, z * y * (1 - c) + x * s, c + z * z * (1 - c)]];
      const apply = (v) => R.map((row) => row[0] * v[0] + row[1] * v[1] + row[2] * v[2]);
      const cols = [0, 1, 2].map((k) => apply(col(k)));
      const p = apply(pos().map((v, k) => v - pivot[k])).map((v, k) => v + pivot[k]);
      for (let r = 0; r < 3; r++) {
        for (let k = 0; k < 3; k++) cam.c2w[r][k] = cols[k][r];
        cam.c2w[r][3] = p[r];
      }
    }
    let dragging = null;
    canvas.addEventListener("pointerdown", (e) => {
      dragging = [e.clientX, e.clientY];
      try { canvas.setPointerCapture(e.pointerId); } catch (_) { /* a synthetic event has no active pointer */ }
    });
    canvas.addEventListener("pointerup", () => { dragging = null; });
    canvas.addEventListener("pointermove", (e) => {
      if (!dragging) return;
      const dx = e.clientX - dragging[0], dy = e.clientY - dragging[1];
      dragging = [e.clientX, e.clientY];
      rotate(upAxis, -0.01 * dx);
      rotate(col(0), -0.01 * dy);
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      const f = Math.exp(0.001 * e.deltaY);
      const p = pos();
      for (let r = 0; r < 3; r++) cam.c2w[r][3] = pivot[r] + f * (p[r] - pivot[r]);
    }, { passive: false });

    // --- loop + FPS counter
    const fpsBox = document.getElementById("fps");
    let frames = 0, since = performance.now();
    function frame(now) {
      try {
        draw(cam);
        if (!window.neurasReady) {
          gl.finish();
          const err = gl.getError();
          if (err !== gl.NO_ERROR) throw new Error(`WebGL error 0x${err.toString(16)} in the first frame`);
          window.neurasReady = true;
        }
      } catch (e) {
        fail(e);
        return;
      }
      frames += 1;
      if (now - since >= 1000) {
        fpsBox.textContent = `${(1000 * frames / (now - since)).toFixed(1)} fps, ${cam.width}x${cam.height}, camera ${camIndex}`
          + (camerasJson.default_orbit ? " (default orbit)" : "");
        frames = 0;
        since = now;
      }
      requestAnimationFrame(frame);
    }
    window.neurasTimeFrames = (count) => {   // ms of each of `count` frames, each finished before the next
      const pixel = new Uint8Array(4), times = [];
      for (let i = 0; i < count; i++) {
        const t = performance.now();
        draw(cam);
        gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, pixel);
        times.push(performance.now() - t);
      }
      return times;
    };
    requestAnimationFrame(frame);
  }

  run().catch(fail);
})();
