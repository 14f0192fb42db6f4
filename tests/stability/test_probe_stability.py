"""The check's probes against the real renderer and on the constructed extreme fields (neuras_distill.stability)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from neuras_distill.render.volume import VolumeRenderer
from neuras_distill.scenes.synthetic import make_scene
from neuras_distill.stability.extreme import make_extreme
from neuras_distill.stability.probe import OPACITY_TOL, probe_field
from neuras_distill.stability.report import Item, StabilityReport

S = pytest.mark.stability


def _mean_opacity_error(field, steps, ref_steps=2048, views=2):
    cams = field.default_cameras(views, 32, 32)
    err = []
    for i in range(views):
        a = VolumeRenderer(field, num_steps=steps, occupancy=None).render(cams, i)["opacity"]
        b = VolumeRenderer(field, num_steps=ref_steps, occupancy=None).render(cams, i)["opacity"]
        hit = (a > 0) | (b > 0)
        err.append(np.abs(a - b)[hit])
    return float(np.concatenate(err).mean())


@S(case="stiff shell σ=1e6: probe vs renderer", family="check",
   reference="VolumeRenderer at 2048 steps on 2 views 32x32: mean |Δopacity| over covered pixels",
   tolerance="at the probe's steps_needed (1024) <= 2x the probe tolerance 0.005; at 256 > 10x")
def test_thin_shell_steps_match_renderer():
    field = make_extreme("thin-shell")
    report = probe_field(field)
    item = report.item("density.stiffness")
    assert item.verdict == "adapted" and report.adaptations["teacher.num_steps"] == item.values["steps_needed"] == 1024
    assert _mean_opacity_error(field, 1024) <= 2 * OPACITY_TOL
    assert _mean_opacity_error(field, 256) > 10 * OPACITY_TOL


@S(case="solid cube σ=1e8: stiff but nothing skipped", family="check",
   reference="a solid object saturates at any step: no adaptation", tolerance="verdict fine; renderer 256 vs 2048 <= 0.005")
def test_solid_stiff_is_fine():
    field = make_extreme("solid-1e8")
    report = probe_field(field)
    assert report.verdict == "fine", report.to_table()
    assert report.item("density.stiffness").values["sigma_delta_max"] > 1e5
    assert _mean_opacity_error(field, 256) <= OPACITY_TOL


@S(case="thin NeuS plate inv_s=1e5: zero crossing between lattice points", family="check",
   reference="plate 0.003 thick, lattice cell 0.0031: found by the probe rays; mesh grid raised above 1/thickness",
   tolerance="surface fine; geometry.grid_resolution >= 1 / 0.003 and the mesh at that grid exists")
@pytest.mark.slow
def test_sharp_plate():
    report = probe_field(make_extreme("sharp-plate"))
    assert report.item("surface.present").verdict == "fine"
    assert report.item("surface.present").values["found_by"] == "probe rays only"
    res = report.adaptations["geometry.grid_resolution"]
    assert res >= 1 / 0.003
    from neuras_distill.geometry.marching import marching_cubes_field
    mesh = marching_cubes_field(make_extreme("sharp-plate"), res)
    z = mesh.vertices[:, 2]
    assert mesh.num_faces > 0 and np.abs(z).max() <= 0.0015 + 1e-6


@S(case="demo bunny: every probe fine", family="check", reference="the demo distils unchanged (README)",
   tolerance="verdict fine, no adaptation, probe < 5 s")
def test_bunny_fine():
    report = probe_field(make_scene("bunny"))
    assert report.verdict == "fine" and report.adaptations == {}, report.to_table()
    assert report.seconds < 5


@S(case="NaN density corner", family="check",
   reference="adapted (treated as empty) with the NaN box [0.4, 0.5]^3", tolerance="bbox within one lattice cell")
def test_nan_corner():
    item = probe_field(make_extreme("nan-corner")).item("finite.geometry")
    assert item.verdict == "adapted"
    lo, hi = np.array(item.values["bbox"])
    cell = 1.0 / 64
    assert np.all(np.abs(lo - 0.4) <= cell) and np.all(np.abs(hi - 0.5) <= cell)


class NaNColour:
    kind = "sdf"

    def __init__(self):
        from neuras_distill.scenes.analytic import SphereSDF
        self.s = SphereSDF(radius=0.5)
        self.aabb, self.inv_s = self.s.aabb, 1000.0

    def geometry(self, x):
        return self.s.geometry(x)

    def radiance(self, x, d):
        c = self.s.radiance(x, d)
        return torch.where((x[:, 2] > 0.3)[:, None], float("nan"), c)


@S(case="NaN colour", family="check", reference="refused: the teacher would composite NaN pixels (measured)",
   tolerance="exact message prefix")
def test_nan_colour_refused():
    report = probe_field(NaNColour(), samples=32, rays=64)
    assert report.verdict == "refused"
    assert report.reason().startswith("finite.colour: radiance() returns NaN/Inf at ")


@S(case="report JSON and table", family="check", reference="json.dumps(allow_nan=False) round trip; one row per item",
   tolerance="exact")
def test_report_serialisation():
    report = probe_field(make_extreme("nan-corner"), samples=24, rays=32)
    data = json.loads(json.dumps(report.to_json(), allow_nan=False))
    assert data["verdict"] == "adapted" and len(data["items"]) == len(report.items)
    table = report.to_table()
    assert all(it.name in table for it in report.items)
    r = StabilityReport("x", "density", [Item("a", "f", {}, "adapted", "", {"teacher.num_steps": 512}),
                                         Item("b", "f", {"v": float("nan")}, "adapted", "", {"teacher.num_steps": 1024})])
    assert r.adaptations == {"teacher.num_steps": 1024} and r.to_json()["items"][1]["values"]["v"] == "nan"
    with pytest.raises(ValueError):
        Item("c", "f", {}, "maybe", "")
