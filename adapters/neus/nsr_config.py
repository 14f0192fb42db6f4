"""bennyguo/instant-nsr-pl run configs: the model section a hash-grid NeuS field needs
(docs/formats.md §2.2).

The hyper-parameters are not in the checkpoint: the defaults are instant-nsr-pl's
``configs/neus-blender.yaml`` (:data:`NSR_DEFAULT_MODEL`), overridable with a dict or the run's
``parsed.yaml`` (:func:`read_nsr_config`). :func:`hash_grid_config` turns ``geometry.xyz_encoding_config``
into a :class:`HashGridConfig`; :func:`grid_alternatives` suggests configs matching a grid's parameter
count when the given one does not.
"""

from __future__ import annotations

import json
from pathlib import Path

from neuras_distill.errors import BadInputError, require

# instant-nsr-pl configs/neus-blender.yaml @ e5fe3f2 (the model section's parts the field needs)
NSR_DEFAULT_MODEL: dict = {
    "radius": 1.5,
    "geometry": {
        "feature_dim": 13,
        "xyz_encoding_config": {"otype": "HashGrid", "n_levels": 16, "n_features_per_level": 2,
                                "log2_hashmap_size": 19, "base_resolution": 32,
                                "per_level_scale": 1.3195079107728942, "include_xyz": True},
        "mlp_network_config": {"otype": "VanillaMLP", "activation": "ReLU", "output_activation": "none",
                               "n_neurons": 64, "n_hidden_layers": 1, "sphere_init": True,
                               "sphere_init_radius": 0.5, "weight_norm": True},
    },
    "texture": {
        "dir_encoding_config": {"otype": "SphericalHarmonics", "degree": 4},
        "mlp_network_config": {"otype": "FullyFusedMLP", "activation": "ReLU", "output_activation": "none",
                               "n_neurons": 64, "n_hidden_layers": 2},
        "color_activation": "sigmoid",
    },
}


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_nsr_config(config) -> dict:
    """instant-nsr-pl config -> the full parsed dict (``{"model": ..., ...}`` or a bare model section).

    ``config`` is a dict, or a path to the run's ``config/parsed.yaml`` (YAML needs PyYAML; a JSON file
    works without it — JSON is valid YAML).
    """
    if isinstance(config, dict):
        return config
    path = Path(config)
    require(path.is_file(), f"config {path} does not exist (give instant-nsr-pl's <run>/config/parsed.yaml)")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInputError(f"config {path} cannot be read as text: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        from ..yaml_text import load_yaml

        data = load_yaml(text, f"config {path}")
    require(isinstance(data, dict), f"config {path} does not hold a mapping (got {type(data).__name__})")
    return data


def nsr_model_config(config=None) -> dict:
    """The model section (defaults of neus-blender.yaml overridden by ``config``, full or model-only)."""
    if config is None:
        return _merge(NSR_DEFAULT_MODEL, {})
    data = read_nsr_config(config)
    model = data.get("model", data)
    require(isinstance(model, dict), "config: 'model' is not a mapping")
    return _merge(NSR_DEFAULT_MODEL, model)


def hash_grid_config(enc: dict):
    """``geometry.xyz_encoding_config`` -> :class:`~neuras_distill.components.tcnn.HashGridConfig`."""
    from neuras_distill.components.tcnn import HashGridConfig

    otype = str(enc.get("otype", "HashGrid"))
    require(otype in ("HashGrid", "ProgressiveBandHashGrid"),
            f"geometry.xyz_encoding_config.otype {otype!r} is not supported (HashGrid, ProgressiveBandHashGrid)")
    enc = {k: v for k, v in enc.items() if k in ("n_levels", "n_features_per_level", "log2_hashmap_size",
                                                 "base_resolution", "per_level_scale", "interpolation")}
    enc["otype"] = "HashGrid"
    return HashGridConfig.from_json(enc)


def grid_alternatives(n: int, cfg) -> list[str]:
    """Simple configs (same N_min and per_level_scale) whose parameter count is n."""
    from neuras_distill.components.tcnn import HashGridConfig

    hits = []
    for f in (2, 1, 4, 8):
        for log2 in range(10, 25):
            for levels in range(1, 33):
                c = HashGridConfig(levels, f, log2, cfg.base_resolution, cfg.per_level_scale, cfg.interpolation)
                if c.n_params() == n:
                    hits.append(f"n_levels={levels}, n_features_per_level={f}, log2_hashmap_size={log2}")
    return hits[:3]
