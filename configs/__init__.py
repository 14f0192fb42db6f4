"""Presets: TOML files that override ``neuras_distill.config.DistillConfig`` defaults (installed as
``neuras_distill.configs``)."""
