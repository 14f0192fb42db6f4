"""bennyguo/instant-nsr-pl hash-grid NeuS checkpoints (``*.ckpt``): :class:`HashGridNeuSField`
(docs/formats.md §2.2).

A PyTorch-Lightning checkpoint (``state_dict`` with prefix ``model.``): TCNN hash grid on ``(x + r) / 2r``
(+ ``2·x_net − 1`` when ``include_xyz``), weight-norm VanillaMLP with biases (Softplus(100) when
``sphere_init``), colour from a TCNN MLP on ``[feature, SH4(d), normalize(∇sdf)]``. Its hyper-parameters come
from the run's config (:mod:`.nsr_config`); the grid's parameter count is checked against the config before
anything is allocated. The world-frame Field contract is :class:`~.base.NeuSFamilyField`'s.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from neuras_distill.errors import BadInputError, require

from .base import DEFAULT_CHUNK, NeuSFamilyField
from .layers import activation, find_entry, layer_indices, linear_from_state, run_mlp, shape_of, softplus100
from .nsr_config import grid_alternatives, hash_grid_config, nsr_model_config, read_nsr_config


class HashGridNeuSField(NeuSFamilyField):
    """An instant-nsr-pl hash-grid NeuS field in the world frame (see the module docstring).

    Args:
        state_dict: the Lightning ``state_dict`` (with or without the ``model.`` prefix).
        config: None (neus-blender defaults), a dict (full parsed config or the model section) or a path to
            ``parsed.yaml``/JSON.
        scale_mat: (4, 4) similarity from the network frame to the world (DTU-style data); None: identity.
        background_color, cameras, chunk: as :class:`NeuSField`.
    """

    def __init__(self, state_dict: dict, config=None, *, scale_mat=None, background_color=None, cameras=None,
                 chunk: int | None = DEFAULT_CHUNK, source: str = "checkpoint"):
        from neuras_distill.fields.checkpoint import check_finite

        require(isinstance(state_dict, dict),
                f"{source}: 'state_dict' is a {type(state_dict).__name__}, not a dict")
        sd = {k[6:] if isinstance(k, str) and k.startswith("model.") else k: v for k, v in state_dict.items()}
        self.source = source
        self.model_config = model = nsr_model_config(config)
        self.radius = self._radius(sd, config, float(model["radius"]), source)
        self.notes: list[str] = []
        if any(isinstance(k, str) and k.startswith(("geometry_bg.", "texture_bg.")) for k in sd):
            self.notes.append("the learned background model (geometry_bg/texture_bg) is not loaded; "
                              "background_color is used instead")
        var_key, var = find_entry(sd, "variance.variance")
        require(var is not None, f"{source}: missing 'model.variance.variance' (the NeuS sharpness)")
        grid_params = self._checked_grid_params(sd, model["geometry"]["xyz_encoding_config"])
        check_finite({k: v for k, v in sd.items() if isinstance(k, str) and k.startswith(
            ("geometry.encoding", "geometry.network", "texture.", "variance."))}, source)
        self._build_geometry(sd, model["geometry"], grid_params)
        self._build_texture(sd, model["texture"])

        per_point = 12 * (sum(w.shape[0] for w, _ in self._geo_layers) + 64) + 600 * self.grid_config.n_levels
        self._place(scale_mat=scale_mat, variance=({"v": var}, "v", f"{source}: {var_key}"),
                    box_half=self.radius, background_color=background_color, cameras=cameras, chunk=chunk,
                    bytes_per_point=per_point)

    def _checked_grid_params(self, sd: dict, enc_cfg: dict) -> torch.Tensor:
        """The flat hash-grid table, its length checked against the config before anything is allocated."""
        source = self.source
        key, params = find_entry(sd, "geometry.encoding.encoding.params",
                                 "geometry.encoding.encoding.encoding.params")
        require(params is not None, f"{source}: missing 'model.geometry.encoding.encoding.params' (the hash "
                                    "grid); not an instant-nsr-pl hash-grid NeuS checkpoint")
        require(isinstance(params, torch.Tensor) and params.ndim == 1,
                f"{source}: {key!r} should be a flat tensor, got shape {shape_of(params)}")
        self.grid_config = gcfg = hash_grid_config(enc_cfg)
        self.include_xyz = bool(enc_cfg.get("include_xyz", False))
        n_grid = gcfg.n_params()
        if params.numel() != n_grid:
            alts = grid_alternatives(int(params.numel()), gcfg)
            hint = (f"; with base_resolution={gcfg.base_resolution} and per_level_scale="
                    f"{gcfg.per_level_scale:.6g} these match: {' | '.join(alts)}") if alts else ""
            raise BadInputError(
                f"{source}: the hash grid {key!r} has {params.numel():,} parameters but the config "
                f"(n_levels={gcfg.n_levels}, n_features_per_level={gcfg.n_features_per_level}, "
                f"log2_hashmap_size={gcfg.log2_hashmap_size}, base_resolution={gcfg.base_resolution}) gives "
                f"{n_grid:,}; pass config=<run>/config/parsed.yaml (or a dict with model.geometry."
                f"xyz_encoding_config){hint}")
        return params

    def _build_geometry(self, sd: dict, geo: dict, grid_params: torch.Tensor) -> None:
        """Hash grid + VanillaMLP (Linear, act, Linear, act, ..., Linear; keys ``layers.0``, ``.2``, ...)."""
        from neuras_distill.components.tcnn import HashGridEncoding

        mlp_cfg, gcfg = geo["mlp_network_config"], self.grid_config
        require(str(mlp_cfg.get("otype", "VanillaMLP")) == "VanillaMLP",
                f"config: geometry.mlp_network_config.otype {mlp_cfg.get('otype')!r} is not supported "
                "(VanillaMLP)")
        for bad in ("sdf_activation", "feature_activation"):
            require(bad not in geo, f"config: geometry.{bad} is not supported")
        src = f"{self.source}: geometry.network"
        geo_sd = {k[len("geometry.network."):]: v for k, v in sd.items()
                  if isinstance(k, str) and k.startswith("geometry.network.")}
        require(geo_sd, f"{self.source}: missing 'model.geometry.network.layers.*' (the SDF MLP)")
        ids = layer_indices(geo_sd, r"^layers\.(\d+)\.", src, "layers.<i>")
        require(ids == list(range(0, 2 * len(ids), 2)),
                f"{src}: layer indices {ids} are not 0, 2, 4, ... (Linear/activation pairs of a VanillaMLP)")
        self._geo_layers = [linear_from_state(geo_sd, f"layers.{i}", src) for i in ids]
        n_in = 3 * int(self.include_xyz) + gcfg.n_output_dims()
        w0 = self._geo_layers[0][0]
        require(w0.shape[1] == n_in,
                f"{src}: 'layers.0' weight has shape {tuple(w0.shape)}, expected input width {n_in} "
                f"({'3 (xyz) + ' if self.include_xyz else ''}{gcfg.n_levels}·{gcfg.n_features_per_level} "
                "grid features); check include_xyz and the grid config")
        for j in range(1, len(ids)):
            prev, w = self._geo_layers[j - 1][0], self._geo_layers[j][0]
            require(w.shape[1] == prev.shape[0],
                    f"{src}: 'layers.{ids[j]}' weight has shape {tuple(w.shape)}, expected input width "
                    f"{prev.shape[0]}")
        self.feature_dim = int(self._geo_layers[-1][0].shape[0])
        cfg_feat = int(geo.get("feature_dim", self.feature_dim))
        require(cfg_feat == self.feature_dim, f"{src}: last layer has {self.feature_dim} outputs but the "
                                              f"config's geometry.feature_dim is {cfg_feat}")
        self._geo_act = softplus100 if mlp_cfg.get("sphere_init", False) else activation(
            mlp_cfg.get("activation", "ReLU"), "geometry.mlp_network_config")
        self._geo_out_act = activation(mlp_cfg.get("output_activation", "none"), "geometry.mlp_network_config")
        self.encoding = HashGridEncoding(gcfg, grid_params.detach().float())
        self.encoding.requires_grad_(False)

    def _build_texture(self, sd: dict, tex: dict) -> None:
        """``[feature, SH4(d), normal]`` -> TCNN MLP (``texture.network.params``) or VanillaMLP -> activation."""
        from neuras_distill.components.tcnn import TcnnMLP, mlp_param_count

        dcfg = tex.get("dir_encoding_config", {})
        require(str(dcfg.get("otype")) == "SphericalHarmonics" and int(dcfg.get("degree", 4)) == 4,
                f"config: texture.dir_encoding_config {dcfg} is not supported (SphericalHarmonics degree 4)")
        tcfg = tex["mlp_network_config"]
        self.texture_in = n_in = self.feature_dim + 16 + 3
        n_in_cfg = tex.get("input_feature_dim")
        require(n_in_cfg is None or int(n_in_cfg) == self.feature_dim + 3,
                f"config: texture.input_feature_dim {n_in_cfg} should be feature_dim + 3 = {self.feature_dim + 3}")
        self._tex_out_act = activation(tcfg.get("output_activation", "none"), "texture.mlp_network_config")
        self._color_act = activation(tex.get("color_activation", "sigmoid"), "texture.color_activation")
        otype = str(tcfg.get("otype", "FullyFusedMLP"))
        key, params = find_entry(sd, "texture.network.params")
        if otype == "VanillaMLP" or params is None:
            tex_sd = {k[len("texture.network."):]: v for k, v in sd.items()
                      if isinstance(k, str) and k.startswith("texture.network.")}
            require(tex_sd, f"{self.source}: missing 'model.texture.network.params' (the colour MLP)")
            src = f"{self.source}: texture.network"
            ids = layer_indices(tex_sd, r"^layers\.(\d+)\.", src, "layers.<i>")
            self._tex_layers = [linear_from_state(tex_sd, f"layers.{i}", src) for i in ids]
            w0, wl = self._tex_layers[0][0], self._tex_layers[-1][0]
            require(w0.shape[1] == n_in, f"{src}: 'layers.{ids[0]}' has input width {w0.shape[1]}, expected {n_in}")
            require(wl.shape[0] == 3, f"{src}: last layer has {wl.shape[0]} outputs, expected 3")
            self._tex_act = activation(tcfg.get("activation", "ReLU"), "texture.mlp_network_config")
            self._texture_mlp = self._vanilla_texture
            return
        require(otype in ("FullyFusedMLP", "CutlassMLP"),
                f"config: texture.mlp_network_config.otype {otype!r} is not supported")
        require(isinstance(params, torch.Tensor) and params.ndim == 1,
                f"{self.source}: {key!r} should be a flat tensor, got shape {shape_of(params)}")
        require(str(tcfg.get("activation", "ReLU")).lower() == "relu",
                "config: texture.mlp_network_config.activation must be ReLU")
        width, n_hidden = int(tcfg.get("n_neurons", 64)), int(tcfg.get("n_hidden_layers", 2))
        aligns = (16, 8) if otype == "FullyFusedMLP" else (8, 16)  # CutlassMLP used 8 before TCNN f00206e
        counts = {a: mlp_param_count(n_in, width, n_hidden, 3, a, a) for a in aligns}
        align = next((a for a in aligns if counts[a] == params.numel()), None)
        require(align is not None,
                f"{self.source}: {key!r} has {params.numel():,} parameters but a {otype} with input {n_in}, "
                f"{n_hidden} hidden layers of {width} and 3 outputs has {counts[aligns[0]]:,}; pass the run's "
                "config (texture.mlp_network_config)")
        self._texture_mlp = TcnnMLP(n_in, width, n_hidden, 3, params.detach().float(), output_alignment=align,
                                    input_alignment=align, pad_value=1.0)  # TCNN pads network inputs with 1.0
        self._texture_mlp.requires_grad_(False)

    def _vanilla_texture(self, h: torch.Tensor) -> torch.Tensor:
        return run_mlp(h, self._tex_layers, self._tex_act)

    @staticmethod
    def _radius(sd: dict, config, cfg_radius: float, source: str) -> float:
        """The box radius: the ``scene_aabb`` buffer when the checkpoint has it (it is what was trained),
        else the config's ``model.radius``; an explicit config radius must agree with the buffer."""
        aabb = sd.get("scene_aabb")
        radius = cfg_radius
        if isinstance(aabb, torch.Tensor) and aabb.numel() == 6 and bool(torch.isfinite(aabb).all()):
            lo, hi = aabb.double().reshape(2, 3)
            r = float(hi.max())
            if torch.allclose(lo, -hi, rtol=1e-5, atol=1e-7) and torch.allclose(hi, torch.full_like(hi, r), rtol=1e-5):
                given = None
                if config is not None:
                    data = read_nsr_config(config)
                    given = (data.get("model", data) or {}).get("radius")
                require(given is None or abs(float(given) - r) <= 1e-5 * r,
                        f"{source}: the checkpoint's scene_aabb has radius {r:g} but the config says "
                        f"model.radius = {given}; give the config of this run")
                radius = r
        require(radius > 0 and math.isfinite(radius), f"config: model.radius must be positive, got {radius}")
        return float(radius)

    def __repr__(self) -> str:
        g = self.grid_config
        return (f"HashGridNeuSField(radius={self.radius}, grid L{g.n_levels} F{g.n_features_per_level} "
                f"T2^{g.log2_hashmap_size} N{g.base_resolution} b{g.per_level_scale:.4g}, "
                f"mlp {len(self._geo_layers)} layers, feature {self.feature_dim}, inv_s={self.inv_s:.4g}, "
                f"{self.frame!r})")

    # -- networks (network frame)
    def sdf_network(self, p: torch.Tensor) -> torch.Tensor:
        """Network-frame points (N, 3) inside ``[-r, r]^3`` -> (N, feature_dim) raw outputs (sdf = column 0)."""
        x = ((p + self.radius) / (2.0 * self.radius)).clamp(0.0, 1.0)
        h = self.encoding(x)
        if self.include_xyz:
            h = torch.cat([x * 2.0 - 1.0, h], dim=-1)
        return self._geo_out_act(run_mlp(h, self._geo_layers, self._geo_act))

    def texture_network(self, features: torch.Tensor, dirs: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
        """instant-nsr-pl ``VolumeRadiance``: (N, F), unit dirs (N, 3), unit normals (N, 3) -> (N, 3)."""
        from neuras_distill.components.tcnn import sh_encode_deg4

        h = torch.cat([features, sh_encode_deg4(dirs), normals], dim=-1)
        return self._color_act(self._tex_out_act(self._texture_mlp(h)))

    def _outside(self, p: torch.Tensor) -> torch.Tensor:
        return (p - p.clamp(-self.radius, self.radius)).norm(dim=-1)

    # -- hooks of NeuSFamilyField (network frame)
    def _local_sdf(self, p: torch.Tensor) -> torch.Tensor:
        return self.sdf_network(p)[:, 0] + self._outside(p)

    def _features(self, out: torch.Tensor) -> torch.Tensor:
        return out  # instant-nsr-pl's feature is the whole geometry output, SDF included

    def _colour(self, p: torch.Tensor, grad: torch.Tensor, d: torch.Tensor,
                features: torch.Tensor) -> torch.Tensor:
        n = F.normalize(grad, dim=-1, eps=1e-12)
        return self.texture_network(features, F.normalize(d, dim=-1), n)
