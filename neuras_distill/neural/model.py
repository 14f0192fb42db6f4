"""The neural texture model: feature atlas -> (vector quantization) -> bilinear blend -> MLP shader.

Owns: :class:`NeuralTextureModel`. What trains is exactly what plays: the forward pass gathers the four
bilinear corner texels of each sample, quantizes only those (deduplicated), blends the *quantized* corners
with the bilinear weights (in the fixed order c00, c10, c01, c11, as the shader does) and runs the MLP. The
baked shader does texelFetch of the four corner code indices, looks up the codes, blends with the same
weights and runs the same MLP.

VQ schedule: ``use_vq`` models start with continuous features (``vq_active`` False) and switch to quantized
features with :meth:`start_vq` (k-means init of the codebook from the current texels); ``fit`` does this
after a warm-up. Touched texels (corner texels with a non-zero weight in a training forward) are recorded in
``touched`` while ``record_touched`` is True; :meth:`fill_unseen_texels` copies the nearest touched texel's
feature into every untouched one (gutter fill), so playback from new views never reads an untrained texel.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy import ndimage
from torch import nn

from neuras_distill.config import TextureConfig
from neuras_distill.errors import BadInputError
from neuras_distill.neural.shader import MLPShader
from neuras_distill.neural.shader_inputs import ShaderInputs
from neuras_distill.neural.texture import NeuralTexture, bilinear_corners
from neuras_distill.neural.vq import VectorQuantizer

#: The library's defaults are the configuration's (one place: ``config.py``).
_TEXTURE = TextureConfig()


def view_inputs(dirs, face_id, normals, use_facing: bool, core_faces: int | None = None,
                reflect: bool = False) -> np.ndarray:
    """The MLP's view input per pixel: (..., 3) unit directions; with ``use_facing`` (..., 4) with ``|n . d|``
    appended (n: the pixel's shading normal, ``GBuffer.normal``; 0 where no face covers the pixel); with
    ``core_faces`` (a two-layer mesh, ``MeshData.core_faces``) one more column, the pixel's mesh layer (0 core,
    1 shell), which picks the shader (:class:`NeuralTextureModel` with ``mesh_layers=2``). With ``reflect``
    the direction columns of covered pixels are ``d - 2 (n . d) n``, the direction reflected about the shading
    normal (GLSL's ``reflect(d, n)``); uncovered pixels keep ``d`` (the skyboxes read them).

    Args:
        dirs: (..., 3) float32 unit view directions (camera to surface).
        face_id: (...) int face index per pixel (-1: uncovered), as in ``GBuffer.face_id``.
        normals: (..., 3) float32 unit shading normal per pixel (``GBuffer.normal``), in the frame of ``dirs``.
    """
    dirs = np.asarray(dirs, dtype=np.float32)
    face_id = np.asarray(face_id)
    columns = [reflected_directions(dirs, normals, face_id >= 0) if reflect else dirs]
    if use_facing:
        facing = np.abs(np.einsum("...i,...i->...", np.asarray(normals, np.float32), dirs))
        columns.append(np.where(face_id >= 0, facing, 0.0).astype(np.float32)[..., None])
    if core_faces is not None:
        columns.append((face_id >= int(core_faces)).astype(np.float32)[..., None])
    return columns[0] if len(columns) == 1 else np.concatenate(columns, axis=-1)


def reflected_directions(dirs: np.ndarray, normals, covered: np.ndarray) -> np.ndarray:
    """(..., 3) float32: ``dirs`` reflected about the unit ``normals`` (..., 3) where ``covered`` (...), else
    ``dirs`` unchanged."""
    n = np.asarray(normals, np.float32)
    reflected = dirs - 2.0 * np.einsum("...i,...i->...", n, dirs)[..., None] * n
    return np.where(covered[..., None], reflected, dirs).astype(np.float32)


class NeuralTextureModel(nn.Module):
    """(uv, view direction) -> rgb.

    Args:
        tex_height, tex_width: atlas size H x W (texels).
        feature_dim: D channels per texel.
        num_codes: K codes of the codebook (used only when use_vq).
        hidden, num_layers: MLP shader size (num_layers Linear layers).
        output_layers: colour layers each shader composites into rgb (``MLPShader``).
        use_viewdir: feed the view direction to the MLP.
        use_facing: also feed |n . d| (``MLPShader``); then ``dirs`` carry 4 columns (direction, facing).
        view_reflect: the direction columns of ``dirs`` are the view direction reflected about the shading
            normal (:func:`view_inputs` with ``reflect``; the baked shader computes the same). The model only
            records it: its forward pass reads the columns whatever they hold.
        use_vq: quantize features (required to bake atlases with more than 65535 texels).
        sparse_grad: texture gradients as sparse tensors (train the texture with SparseAdam).
        mesh_layers: 2 for a two-layer mesh (``MeshData.core_faces``): the core and the shell get a shader each
            (same depth and inputs; the shell's width is ``shell_hidden``), picked per pixel by the layer column
            :func:`view_inputs` appends to ``dirs``.
            One shader for both cost the gradient ball's interior 4.6 dB on training views (41.3 vs 45.9 dB)
            and its silhouette band 2.9 dB: the shell's fade (surface colour to background with the angle) took
            the shared MLP's capacity. Both run at the same per-pixel cost (a uniform branch in GLSL).
        core_viewdir: with ``mesh_layers=2``, whether the core's shader takes the view direction (None: as
            ``use_viewdir``; the shell's always follows ``use_viewdir``). A core at the level where the field's
            colour comes from (``geometry.colour_level``) sees no parallax through the fringe, and the view input
            then only lets it overfit the training directions when the field's own colour does not change with
            the view: on the gradient ball (held-out 640x360, same mesh, 3000 steps, no VQ) the core's interior
            scored 41.3 dB without the direction and 39.3 dB with it. ``use_viewdir`` then says whether any
            shader takes it (the direction columns of ``dirs`` are there either way).
        shell_hidden: with ``mesh_layers=2``, the hidden width of the shell's shader (None or 0: ``hidden``).
            Its fragments are only those outside the core's silhouette, so a wider shell costs little.
        quantize_above: with use_vq, the most touched texels that stay exact after training instead of being
            quantized (:meth:`start_vq`); 0: always quantize.
        coarse_factor: a coarse feature level this many times fewer texels a side under the atlas
            (:class:`NeuralTexture`); 1: none.
        pages: P atlas pages of ``tex_width`` squared texels stacked along v (``tex_height = P * tex_width``;
            ``geometry.unwrap(page_size=)``): the bilinear lookup stays within a uv's page
            (``texture.bilinear_corners``), as the baked shader's texture-array lookup does.
    """

    @classmethod
    def for_atlas(cls, config: TextureConfig, tex_height: int, tex_width: int, inputs: ShaderInputs, *,
                  pages: int = 1, mesh_layers: int = 1, coarse_factor: int | None = None) -> NeuralTextureModel:
        """The model the texture section ``config`` describes (feature_dim, num_codes, hidden, num_layers,
        output_layers, shell_hidden, quantize, quantize_above, coarse_factor unless the pipeline chose another) for a
        ``tex_height`` x ``tex_width`` atlas of ``pages`` pages, with the mesh's layers and the shader ``inputs``
        the pipeline chose (``neural.shader_inputs.ShaderInputs``, taken whole)."""
        return cls(tex_height, tex_width, feature_dim=config.feature_dim, num_codes=config.num_codes,
                   hidden=config.hidden, num_layers=config.num_layers, output_layers=config.output_layers,
                   use_viewdir=inputs.use_viewdir, use_vq=config.quantize, use_facing=inputs.use_facing,
                   mesh_layers=mesh_layers, core_viewdir=inputs.core_viewdir, view_reflect=inputs.reflect,
                   shell_hidden=config.shell_hidden, pages=pages, quantize_above=config.quantize_above,
                   coarse_factor=config.coarse_factor if coarse_factor is None else coarse_factor)

    def __init__(self, tex_height: int, tex_width: int, feature_dim: int = _TEXTURE.feature_dim,
                 num_codes: int = _TEXTURE.num_codes, hidden: int = _TEXTURE.hidden,
                 num_layers: int = _TEXTURE.num_layers, use_viewdir: bool = True, use_vq: bool = _TEXTURE.quantize,
                 sparse_grad: bool = True, dead_after: int = 100, use_facing: bool = False,
                 mesh_layers: int = 1, core_viewdir: bool | None = None, shell_hidden: int | None = None,
                 pages: int = 1, quantize_above: int = _TEXTURE.quantize_above,
                 coarse_factor: int = _TEXTURE.coarse_factor,
                 output_layers: int = _TEXTURE.output_layers, view_reflect: bool = False) -> None:
        super().__init__()
        self.tex_height, self.tex_width, self.feature_dim = int(tex_height), int(tex_width), int(feature_dim)
        self.pages = int(pages)
        if self.pages < 1 or (self.pages > 1 and self.tex_height != self.pages * self.tex_width):
            raise ValueError(f"{self.pages} atlas pages need tex_height = pages * tex_width, got "
                             f"{self.tex_height} x {self.tex_width}")
        self.hidden, self.num_layers = int(hidden), int(num_layers)
        self.use_viewdir, self.use_vq, self.sparse_grad = bool(use_viewdir), bool(use_vq), bool(sparse_grad)
        self.view_reflect = bool(view_reflect) and self.use_viewdir
        self.texture = NeuralTexture(self.tex_height, self.tex_width, self.feature_dim,
                                     coarse_factor=coarse_factor, pages=self.pages)
        self.vq = VectorQuantizer(num_codes, self.feature_dim, dead_after=dead_after) if self.use_vq else None
        if mesh_layers not in (1, 2):
            raise ValueError(f"mesh_layers must be 1 or 2, got {mesh_layers}")
        if core_viewdir is not None and mesh_layers == 1 and bool(core_viewdir) != bool(use_viewdir):
            raise ValueError("core_viewdir differs from use_viewdir only on a two-layer mesh (mesh_layers=2)")
        core_dir = bool(use_viewdir) if core_viewdir is None else bool(use_viewdir) and bool(core_viewdir)
        widths = (int(hidden), int(shell_hidden or hidden))
        self.shaders = nn.ModuleList(MLPShader(self.feature_dim, hidden=widths[layer], num_layers=num_layers,
                                               use_viewdir=core_dir if layer == 0 else use_viewdir,
                                               use_facing=use_facing, output_layers=output_layers)
                                     for layer in range(mesh_layers))
        self.register_buffer("vq_active", torch.tensor(False))
        self.quantize_above = int(quantize_above)
        self.register_buffer("vq_skipped", torch.tensor(False))     # start_vq kept the texels exact
        self.register_buffer("touched", torch.zeros(self.tex_height * self.tex_width, dtype=torch.bool),
                             persistent=False)
        self.record_touched = False
        if self.vq is not None:
            self.vq.owned_codes = self._owned_codes

    @torch.no_grad()
    def trained_texel_codes(self) -> torch.Tensor:
        """(M,) int64: the nearest code of every touched texel (of all texels before any was recorded)."""
        flat = self.texture.features_flat()
        sel = torch.nonzero(self.touched).flatten()
        return self.vq.quantize_all(flat[sel] if sel.numel() else flat)

    @torch.no_grad()
    def _owned_codes(self) -> torch.Tensor:
        """(K,) bool: codes the touched texels (all texels before any was recorded) quantize to now."""
        owned = torch.zeros(self.vq.num_codes, dtype=torch.bool, device=self.texture.data.device)
        owned[self.trained_texel_codes()] = True
        return owned

    @property
    def shader(self) -> MLPShader:
        """The (core's) MLP shader."""
        return self.shaders[0]

    @property
    def mesh_layers(self) -> int:
        return len(self.shaders)

    @property
    def view_columns(self) -> int:
        """Columns of ``dirs`` (:func:`view_inputs`): 3 directions, + facing, + the layer with two layers."""
        return 3 + int(self.use_facing) + int(self.mesh_layers == 2)

    @property
    def use_facing(self) -> bool:
        """Whether the shader takes the facing cosine |n . d| (``dirs`` then carry 4 columns)."""
        return self.shader.use_facing

    @property
    def num_codes(self) -> int:
        return self.vq.num_codes if self.vq is not None else 0

    @property
    def quantizing(self) -> bool:
        return self.vq is not None and bool(self.vq_active)

    # ------------------------------------------------------------------ forward
    def features(self, uv: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """Blended (quantized) features at uv (B, 2) -> (B, D) float32, aux (vq_loss, indices (B, 4) or None)."""
        idx, w = bilinear_corners(uv, self.tex_height, self.tex_width, self.pages)
        if self.record_touched and self.training:
            with torch.no_grad():
                self.touched[idx[w > 0]] = True
        if self.quantizing and not self.training and not torch.is_grad_enabled():
            # playing the trained model (bake, plain texture, evaluation): every texel's code once, reused
            uniq, inv = torch.unique(idx, return_inverse=True)
            codes = self.vq.quantize_all(self.texture.features_flat().float())[uniq]
            corners = self.vq.codebook.detach()[codes][inv]
            aux = {"vq_loss": torch.zeros((), device=uv.device), "indices": codes[inv]}
        elif self.quantizing:
            uniq, inv = torch.unique(idx, return_inverse=True)
            z = self.texture.gather(uniq, sparse_grad=self.sparse_grad)
            zq, codes, vq_loss = self.vq(z)
            corners = zq[inv]                     # (B, 4, D)
            aux = {"vq_loss": vq_loss, "indices": codes[inv]}
        else:
            corners = self.texture.gather(idx, sparse_grad=self.sparse_grad)
            aux = {"vq_loss": torch.zeros((), device=uv.device), "indices": None}
        w = w.to(corners.dtype)
        f = (w[:, 0:1] * corners[:, 0] + w[:, 1:2] * corners[:, 1]
             + w[:, 2:3] * corners[:, 2] + w[:, 3:4] * corners[:, 3])
        return f, aux

    def forward(self, uv: torch.Tensor, dirs: torch.Tensor | None = None) -> tuple[torch.Tensor, dict]:
        """uv (B, 2), dirs (B, :attr:`view_columns`) (:func:`view_inputs`) -> rgb (B, 3) in (0, 1),
        aux {"vq_loss", "indices"}."""
        f, aux = self.features(uv)
        if self.mesh_layers == 1:
            return self.shader(f, dirs), aux
        shell = dirs[:, -1] > 0.5
        rgb = torch.empty(f.shape[0], 3, dtype=f.dtype, device=f.device)
        for layer, rows in ((0, torch.nonzero(~shell).flatten()), (1, torch.nonzero(shell).flatten())):
            if rows.numel():
                rgb = rgb.index_put((rows,), self.shaders[layer](f[rows], dirs[rows, :-1]))
        return rgb, aux

    # ------------------------------------------------------------------ training helpers
    @torch.no_grad()
    def start_vq(self, sample: torch.Tensor | None = None, max_samples: int = 65536,
                 after_training: bool = False) -> None:
        """Switch to quantized features: k-means init of the codebook from ``sample`` (M, D), by default the
        touched texels (all texels when none were recorded). ``after_training`` (the model's last step, with
        the touched texels of every rank): when at most ``quantize_above`` texels were touched, nothing is
        quantized: ``vq_skipped`` is set and every texel keeps its own feature (:meth:`baked_features` stores
        them exactly)."""
        if self.vq is None:
            raise RuntimeError("model was built with use_vq=False")
        if after_training and sample is None and 0 < int(self.touched.sum()) <= self.quantize_above:
            self.vq_skipped.fill_(True)
            return
        self.texture.fold_coarse()
        if sample is None:
            flat = self.texture.flat.detach()
            sel = torch.nonzero(self.touched).flatten()
            if sel.numel() == 0:
                sel = torch.arange(flat.shape[0])
            if sel.numel() > max_samples:
                sel = sel[torch.randperm(sel.numel())[:max_samples]]
            sample = flat[sel]
        self.vq.init_from(sample, max_samples=max_samples)
        self.vq_active.fill_(True)

    def reset_touched(self) -> None:
        self.touched.zero_()

    @torch.no_grad()
    def fill_unseen_texels(self, touched_mask: torch.Tensor | np.ndarray | None = None) -> int:
        """Copy into every untouched texel the feature of the nearest touched texel (Euclidean, in texels).

        Args:
            touched_mask: (H, W) bool; default: the recorded ``touched`` buffer.
        Returns:
            number of texels filled (0 when nothing or everything was touched).
        """
        if touched_mask is None:
            touched_mask = self.touched.view(self.tex_height, self.tex_width)
        mask = np.asarray(touched_mask.cpu() if torch.is_tensor(touched_mask) else touched_mask, dtype=bool)
        if mask.shape != (self.tex_height, self.tex_width):
            raise ValueError(f"touched_mask must be {(self.tex_height, self.tex_width)}, got {mask.shape}")
        self.texture.fold_coarse()
        if mask.all() or not mask.any():
            return 0
        _, (jj, ii) = ndimage.distance_transform_edt(~mask, return_indices=True)
        src = torch.from_numpy((jj.astype(np.int64) * self.tex_width + ii).reshape(-1))
        flat = self.texture.flat
        unseen = torch.from_numpy(~mask.reshape(-1))
        flat.data[unseen] = flat.data[src[unseen]]
        return int(unseen.sum())

    # ------------------------------------------------------------------ baking
    @torch.no_grad()
    def baked_features(self) -> tuple[np.ndarray, np.ndarray]:
        """What the shader reads: (index map (H, W) int64, codebook (K', D) float32), unused codes dropped.

        With use_vq the index map is the nearest code of every texel (what the forward pass picks) remapped
        to the pruned codebook. Without VQ the "codebook" is the list of distinct texel features (exact, no
        quantization), which fits the uint16 index texture when there are at most 65535 of them.
        """
        flat = self.texture.features_flat().float()
        if self.quantizing:
            idx = self.vq.quantize_all(flat)
            codebook, remap = self.vq.prune(idx)
            index = remap[idx]
        else:
            if self.use_vq and not bool(self.vq_skipped):
                raise BadInputError("the model's vector quantizer was never switched on (start_vq); "
                                    "train it with fit() before baking")
            # identical texels (untouched ones filled with their nearest touched feature) share one entry:
            # lossless, and an atlas whose distinct features fit 16 bits plays without VQ
            codebook, index = torch.unique(flat, dim=0, return_inverse=True)
            if codebook.shape[0] > 65535:
                raise BadInputError(f"a {self.tex_width}x{self.tex_height} atlas without VQ has {codebook.shape[0]} "
                                    "distinct texel features, more than the 65535 a uint16 index texture can "
                                    "address; use use_vq=True")
        return (index.view(self.tex_height, self.tex_width).cpu().numpy().astype(np.int64),
                codebook.cpu().numpy().astype(np.float32))

    @torch.no_grad()
    def render_gbuffer(self, uv, coverage, dirs, background, chunk: int = 65536) -> np.ndarray:
        """Torch reference render of one G-buffer (for parity tests and evaluation).

        Args:
            uv: (H, W, 2) float32; coverage: (H, W) bool; dirs: (H, W, :attr:`view_columns`) (:func:`view_inputs`);
            background: (3,) colour of uncovered pixels. numpy arrays or tensors.
        Returns:
            (H, W, 3) float32 numpy image.
        """
        was_training = self.training
        self.eval()
        try:
            uv_t = torch.as_tensor(np.asarray(uv, dtype=np.float32))
            cov = torch.as_tensor(np.asarray(coverage, dtype=bool))
            d_t = torch.as_tensor(np.asarray(dirs, dtype=np.float32))
            h, w = cov.shape
            out = torch.empty(h * w, 3)
            out[:] = torch.as_tensor(np.asarray(background, dtype=np.float32)).view(1, 3)
            sel = torch.nonzero(cov.reshape(-1)).flatten()
            uv_f, d_f = uv_t.reshape(-1, 2), d_t.reshape(-1, d_t.shape[-1])
            for s in range(0, sel.numel(), chunk):
                ids = sel[s:s + chunk]
                rgb, _ = self(uv_f[ids], d_f[ids])
                out[ids] = rgb
            return out.view(h, w, 3).numpy()
        finally:
            self.train(was_training)
