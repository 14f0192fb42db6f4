"""``neuras-distill bench``: the front and recommendation on known points, the variants' config changes, bad
input, and a whole bench of a small run whose variants are distilled from the run's stored stages."""

from __future__ import annotations

import json
import shutil

import pytest

from neuras_distill.bench.front import pareto_front, recommend
from neuras_distill.bench.run import parse_resolutions
from neuras_distill.bench.variants import RunFacts, pick_variants, variant_overrides
from neuras_distill.cli import main
from neuras_distill.errors import BadInputError


def _pt(label, ms, psnr, kind="bundle"):
    return {"label": label, "seconds_per_frame": ms / 1000.0, "psnr": psnr, "kind": kind}


def test_pareto_front_keeps_exactly_the_undominated_points():
    pts = [_pt("a", 1.0, 30.0), _pt("b", 2.0, 29.0), _pt("c", 2.0, 33.0), _pt("d", 5.0, 33.0),
           _pt("e", 9.0, 40.0, "field"), _pt("f", 0.5, 20.0)]
    assert pareto_front(pts) == ["f", "a", "c", "e"]
    assert recommend(pts, target_ms=2.5)["label"] == "c"          # fields are never recommended
    assert recommend(pts, target_ms=0.4) is None


def test_resolutions_are_parsed_or_refused_in_one_line():
    assert parse_resolutions("640x360, 1920X1080") == [(640, 360), (1920, 1080)]
    for bad, what in [("abc", "is not WIDTHxHEIGHT"), ("0x0", "outside 8x8"), ("640x", "is not WIDTHxHEIGHT"),
                      ("", "is empty")]:
        with pytest.raises(BadInputError, match=what):
            parse_resolutions(bad)


def test_every_variant_pins_the_runs_training_and_changes_one_setting():
    facts = RunFacts(side=256, steps=3000, face_budget=40000, hidden=32, num_layers=2)
    changes = {v.name: variant_overrides(v, facts) for v in pick_variants(None)}
    assert len(changes) >= 6
    for name, c in changes.items():
        assert c["train"] == {"steps": 3000}, name
    assert changes["atlas-half"]["texture"]["resolution"] == 128
    assert changes["atlas-double"]["texture"]["resolution"] == 512
    assert changes["faces-quarter"]["geometry"] == {"face_budget": 10000}
    assert changes["mlp-two-hidden"]["texture"]["num_layers"] == 3
    assert changes["no-vq"]["texture"]["quantize"] is False
    # a variant that would be the run's own bundle is named as such (and skipped by the bench)
    same = {v.name: v.same_as_run(facts) for v in pick_variants(None)}
    assert not any(same.values())
    without_view = RunFacts(side=256, steps=3000, face_budget=40000, hidden=32, num_layers=2, view_input=False)
    same = {v.name: v.same_as_run(without_view) for v in pick_variants(None)}
    assert [n for n, why in same.items() if why] == ["no-view"] and "already has no view input" in same["no-view"]
    narrow = RunFacts(side=256, steps=3000, face_budget=40000, hidden=16, num_layers=2)
    same = {v.name: v.same_as_run(narrow) for v in pick_variants(None)}
    assert [n for n, why in same.items() if why] == ["mlp-16"] and "already 16 wide" in same["mlp-16"]
    with pytest.raises(BadInputError, match="unknown bench variant 'mlp-64'; available: atlas-half"):
        pick_variants(["mlp-8", "mlp-64"])


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    out = root / "sphere"
    assert main(["from-synthetic", "sphere", "--preset", "fast", "--eval-width", "160", "--steps", "200",
                 "--out", str(out), "--quiet"]) == 0
    return out


@pytest.mark.parametrize("argv,message", [
    (["--resolutions", "0x0"], "outside 8x8"),
    (["--resolutions", "160x120"], "does not match the held-out cameras' aspect ratio (160x90)"),
    (["--variants", "mlp-64"], "unknown bench variant 'mlp-64'"),
])
@pytest.mark.gl  # small_run distils with OpenGL
@pytest.mark.slow
def test_bad_bench_arguments_exit_2_and_write_nothing(small_run, capsys, argv, message):
    assert main(["bench", str(small_run), "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not (small_run / "bench").exists() and not (small_run / ".bench.partial").exists()


@pytest.mark.gl
@pytest.mark.slow
def test_a_folder_that_is_not_a_run_or_has_no_work_area_is_refused(small_run, tmp_path, capsys):
    assert main(["bench", str(tmp_path), "--quiet"]) == 2
    assert "is not a neuras-distill run folder" in capsys.readouterr().err
    bare = tmp_path / "bare"
    shutil.copytree(small_run, bare, ignore=shutil.ignore_patterns("work"))
    assert main(["bench", str(bare), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "without a stored work area" in err and "re-run it with the same command" in err


@pytest.mark.gl
@pytest.mark.slow
def test_bench_distils_variants_from_the_stored_stages_and_writes_the_front(small_run):
    assert main(["bench", str(small_run), "--resolutions", "96x54,160x90", "--variants", "mlp-8,faces-half",
                 "--target-ms", "1000", "--quiet"]) == 0
    folder = small_run / "bench"
    result = json.loads((folder / "bench.json").read_text())
    assert {p.name for p in folder.iterdir()} >= {"bench.json", "bench.md", "bench.png", "variants"}
    assert not (small_run / ".bench.partial").exists()
    for res in ("96x54", "160x90"):
        here = [p for p in result["points"] if p["resolution"] == [int(x) for x in res.split("x")]]
        kinds = [p["kind"] for p in here]
        assert kinds.count("field") == 3 and kinds.count("plain-texture") == 1 and kinds.count("bundle") == 3
        assert [p["label"] for p in here if p["default"]] == ["default"]
        field = [p for p in here if p["kind"] == "field"]
        assert [p["steps"] for p in field] == [32, 64, 128]
        assert field[0]["psnr"] < field[1]["psnr"] < field[2]["psnr"]          # against a denser march
        for p in here:
            assert p["seconds_per_frame"] > 0 and 0 < p["ssim"] <= 1 and 0 <= p["flip"] <= 1
            assert p["reference_steps"] == 256
            if p["kind"] != "field":
                assert p["timing"]["frames"] >= 30 and p["timing"]["p10_ms"] <= p["timing"]["median_ms"]
        front = result["pareto_by_resolution"][res]
        assert front and set(front) <= {p["label"] for p in here}
    assert result["pareto"] == result["pareto_by_resolution"]["160x90"]
    assert result["recommended"] in {"default", "mlp-8", "faces-half"}
    # the variants reused the run's stages: the MLP one re-trained only, the face-budget one re-meshed
    mlp = json.loads((folder / "variants" / "mlp-8" / "report.json").read_text())
    faces = json.loads((folder / "variants" / "faces-half" / "report.json").read_text())
    assert {"teacher", "surface", "geometry", "gbuffer", "field_views"} <= set(mlp["resumed"]["stages"])
    assert {"teacher", "field_views"} <= set(faces["resumed"]["stages"])
    assert "surface" not in faces["resumed"]["stages"] and faces["mesh_faces"] <= 4000
    assert mlp["config"]["texture"]["hidden"] == 8 and mlp["train_summary"]["steps"] == 200
    html = (small_run / "report.html").read_text()
    assert html.count('<section id="bench">') == 1 and "bench/bench.png" in html

    # a killed bench: its finished variant (marker written) is reused, an unfinished one and stray files are not
    partial = small_run / ".bench.partial"
    shutil.copytree(folder / "variants" / "mlp-8", partial / "variants" / "mlp-8")
    (partial / "variants" / "faces-half").mkdir()                      # killed while distilling: no marker
    (partial / "bench.json").write_text("{half written")
    before = (partial / "variants" / "mlp-8" / "report.json").read_bytes()
    assert main(["bench", str(small_run), "--resolutions", "96x54", "--variants", "mlp-8", "--quiet"]) == 0
    again = json.loads((folder / "bench.json").read_text())
    assert again["reused_variants"] == ["mlp-8"] and not partial.exists()
    assert (folder / "variants" / "mlp-8" / "report.json").read_bytes() == before
    assert {p.name for p in (folder / "variants").iterdir()} == {"mlp-8"}
    assert [p["label"] for p in again["points"] if p["kind"] == "bundle"] == ["default", "mlp-8"]


def test_a_variant_is_reused_only_with_the_settings_it_was_distilled_with(tmp_path):
    from neuras_distill.bench.run import VARIANT_MARKER, _finished_variant

    marker = {"source": {"command": "x"}, "config": {"texture": {"hidden": 8}}, "version": "1"}
    (tmp_path / "report.json").write_text('{"psnr": 30}')
    assert _finished_variant(tmp_path, marker) is None                 # no marker: killed before it finished
    (tmp_path / VARIANT_MARKER).write_text(json.dumps(marker))
    assert _finished_variant(tmp_path, marker) == {"psnr": 30}
    assert _finished_variant(tmp_path, {**marker, "config": {"texture": {"hidden": 16}}}) is None
    assert _finished_variant(tmp_path, {**marker, "version": "2"}) is None
    (tmp_path / VARIANT_MARKER).write_text("{torn")
    assert _finished_variant(tmp_path, marker) is None


def test_the_bundle_labels_of_the_plot_never_overlap(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from neuras_distill.pipeline.report import _label_column, plot_tradeoff

    close = [(f"v{i}", 30.0 + 0.01 * i, 29.0 + 0.001 * ((7 * i) % 5)) for i in range(6)]   # within 0.1 ms, 5 mdB
    fig, ax = plt.subplots()
    _label_column(ax, close)
    texts = {t.get_text(): t.xyann[1] for t in ax.texts}
    plt.close(fig)
    slots = sorted(texts.values())
    assert len(texts) == 6 and min(b - a for a, b in zip(slots, slots[1:])) > 0.01
    by_psnr = [label for label, _, _ in sorted(close, key=lambda t: t[2])]
    assert sorted(texts, key=texts.get) == by_psnr                  # labels stacked in the points' PSNR order
    points = [{**_pt(label, ms, psnr), "resolution": [64, 36], "default": label == "v0", "reference_steps": 256}
              for label, ms, psnr in close]
    plot_tradeoff(points, {"64x36": ["v0"]}, tmp_path / "bench.png")
    assert (tmp_path / "bench.png").stat().st_size > 10_000
