"""A scene as tiles (``neuras-distill tiles plan | run | merge``, ``neuras_distill/tiles/``).

The embedded ``blocks`` scene (six blocks on a 3 x 2 ground slab, z up) planned in tiles: the plan is
deterministic and its tiles cover the scene; a cut mesh keeps its surface and texture up to the plane; two tiles
distilled with the fast preset meet without cracks when drawn together, and their tileset is 3D Tiles 1.1 with
one upright glb each. Bad input is one line, exit 2, nothing written.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from neuras_distill.cli import main
from neuras_distill.errors import BadInputError
from neuras_distill.geometry.clip import clip_mesh_to_box
from neuras_distill.geometry.mesh import MeshData

ROOT = Path(__file__).resolve().parents[1]
VALIDATOR = ROOT / ".tools" / "node_modules" / "gltf-validator"


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("neuras-distill: error: ") and "Traceback" not in err, err
    return err


def _plan(out: Path, size: str = "1", *extra: str) -> int:
    return main(["tiles", "plan", "synthetic:blocks", "--tile-size", size, "--out", str(out), "--preset", "fast",
                 *extra])


def test_a_cut_keeps_the_surface_and_its_texture_up_to_the_plane():
    """A 10 x 10 grid of quads over [0, 1]^2 (uv = xy) cut to x <= 0.37, y >= 0.22: the kept area is exactly the
    box's, every new vertex lies on a plane and keeps uv = xy, no edge inside is left open."""
    n = 10
    xs = np.linspace(0, 1, n + 1)
    v = np.stack(np.meshgrid(xs, xs, indexing="xy"), -1).reshape(-1, 2)
    vertices = np.c_[v, np.zeros(len(v))]
    faces = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    mesh = MeshData(vertices, np.array(faces), v.astype(np.float32))
    cut = clip_mesh_to_box(mesh, [-np.inf, 0.22, -1], [0.37, np.inf, 1])
    tri = cut.vertices[cut.faces].astype(np.float64)
    area = 0.5 * np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]).sum()
    assert area == pytest.approx(0.37 * 0.78, rel=1e-5)
    assert cut.vertices[:, 0].max() <= 0.37 + 1e-6 and cut.vertices[:, 1].min() >= 0.22 - 1e-6
    np.testing.assert_allclose(cut.uvs, cut.vertices[:, :2], atol=1e-6)
    # every edge is shared by two faces except on the outline of the kept rectangle (no crack inside)
    edges: dict = {}
    for f in cut.faces:
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            edges[tuple(sorted((int(a), int(b))))] = edges.get(tuple(sorted((int(a), int(b)))), 0) + 1
    for (a, b), count in edges.items():
        if count == 1:
            pa, pb = cut.vertices[a], cut.vertices[b]
            on = [abs(pa[0] - 0.37) < 1e-6 and abs(pb[0] - 0.37) < 1e-6, abs(pa[1] - 0.22) < 1e-6 and
                  abs(pb[1] - 0.22) < 1e-6, pa[0] < 1e-6 and pb[0] < 1e-6, pa[1] > 1 - 1e-6 and pb[1] > 1 - 1e-6]
            assert any(on), (pa, pb)
    assert cut.stats["clipped_faces"]["before"] == 200


def test_a_plan_is_deterministic_and_its_tiles_cover_the_scene(tmp_path, capsys):
    assert _plan(tmp_path / "a") == 0 and _plan(tmp_path / "b") == 0
    assert (tmp_path / "a" / "plan.json").read_bytes() == (tmp_path / "b" / "plan.json").read_bytes()
    assert _plan(tmp_path / "a") == 0                            # the same plan again: nothing changes
    plan = json.loads((tmp_path / "a" / "plan.json").read_text())
    assert plan["up_axis"] == "+z" and plan["ground_axes"] == [0, 1] and len(plan["tiles"]) == 6
    scene = np.asarray(plan["scene_box"])
    area = 0.0
    for tile in plan["tiles"]:
        box, grown = np.asarray(tile["box"]), np.asarray(tile["training_box"])
        assert (grown[0] <= box[0]).all() and (grown[1] >= box[1]).all()
        assert (grown[0] >= scene[0] - 1e-9).all() and (grown[1] <= scene[1] + 1e-9).all()
        assert set(tile["cameras"]) <= set(plan["train"]) and set(tile["held_out"]) <= set(plan["test"])
        assert tile["cameras"] and tile["budget"]["faces"] >= 2000
        area += np.prod((box[1] - box[0])[:2])
    assert area == pytest.approx(np.prod((scene[1] - scene[0])[:2]))
    assert sum(t["budget"]["weight"] for t in plan["tiles"]) == pytest.approx(1.0, abs=1e-5)
    capsys.readouterr()
    assert _plan(tmp_path / "c", "1", "--dry-run") == 0
    table = capsys.readouterr().out
    assert "6 tiles of 1 (+0.1 overlap) on the xy plane" in table and "est. s" in table
    assert not (tmp_path / "c").exists()


def test_bad_plans_and_runs_exit_2_with_one_line_and_write_nothing(tmp_path, capsys):
    assert _plan(tmp_path / "big", "5") == 2
    assert "makes one tile of the whole scene" in _one_line(capsys) and not (tmp_path / "big").exists()
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert _plan(other) == 2 and "holds no tile plan" in _one_line(capsys)
    city = tmp_path / "city"
    assert _plan(city) == 0
    capsys.readouterr()
    assert _plan(city, "1.5") == 2 and "holds another plan" in _one_line(capsys)
    assert main(["tiles", "run", str(city), "--tile", "6"]) == 2
    assert "--tile 6 is out of range: the plan has tiles 0..5" in _one_line(capsys)
    assert main(["tiles", "merge", str(city), "--out", str(tmp_path / "set")]) == 2
    assert "tiles 0, 1, 2, 3, 4, 5 of 6 are not finished" in _one_line(capsys) and not (tmp_path / "set").exists()
    plan = json.loads((city / "plan.json").read_text())
    for change, message in (({"version": 99}, "version 99"), ({"format": "something"}, "not a neuras-distill tile"),
                            ({"field": "0" * 24}, "made for another field")):
        (city / "plan.json").write_text(json.dumps({**plan, **change}))
        assert main(["tiles", "run", str(city), "--tile", "0"]) == 2 and message in _one_line(capsys)
    assert not (city / "tiles").exists()


def test_a_camera_set_that_misses_part_of_the_scene_is_refused():
    """Cameras at x = -0.6 looking towards -x: the tiles at +x lie behind every one of them."""
    import torch

    import neuras_distill as nd
    from neuras_distill.errors import BadInputError
    from neuras_distill.render.cameras import Cameras, look_at
    from neuras_distill.tiles.plan import make_plan

    field = nd.make_scene("blocks")
    c2w = torch.stack([look_at(torch.tensor([-0.6, y, 0.5]), torch.tensor([-1.5, y, 0.0]),
                               torch.tensor([0.0, 0.0, 1.0])) for y in np.linspace(-0.8, 0.8, 12)]).float()
    f = torch.full((12,), 40.0)
    cams = Cameras(c2w, f, f, torch.full((12,), 32.0), torch.full((12,), 32.0), 64, 64)
    with pytest.raises(BadInputError, match="is seen by no training camera"):
        make_plan(field, cams, nd.load_config("fast"), tile_size=1.0, margin=0.1, source={}, fingerprint="x")


@pytest.fixture(scope="session")   # one build: its file is one xdist group (conftest.py)
def two_tiles(tmp_path_factory):
    """The blocks scene in 2 tiles (x < 0, x > 0: the cut runs between blocks through the ground), run and
    merged; (city folder, tileset folder)."""
    city = tmp_path_factory.mktemp("tiles") / "city"
    assert _plan(city, "1.5", "--steps", "600") == 0
    assert main(["tiles", "run", str(city), "--quiet"]) == 0
    assert main(["tiles", "merge", str(city), "--out", str(city / "tileset")]) == 0
    return city, city / "tileset"


@pytest.mark.gl
@pytest.mark.slow
def test_tiles_run_once_and_merge_into_an_upright_tileset(two_tiles, capsys):
    city, tileset = two_tiles
    plan = json.loads((city / "plan.json").read_text())
    assert len(plan["tiles"]) == 2
    capsys.readouterr()
    assert main(["tiles", "run", str(city), "--tile", "1"]) == 0             # finished: skipped, nothing redone
    assert "finished before, skipped" in capsys.readouterr().out
    doc = json.loads((tileset / "tileset.json").read_text())
    assert doc["asset"]["version"] == "1.1" and doc["root"]["refine"] == "ADD"
    children = doc["root"]["children"]
    assert [c["content"]["uri"] for c in children] == ["tiles/0.glb", "tiles/1.glb"]
    for tile, child in zip(plan["tiles"], children):
        centre, half = np.asarray(child["boundingVolume"]["box"][:3]), np.asarray(child["boundingVolume"]["box"][3:])
        box = np.asarray(tile["box"])
        # a z-up capture: the tileset frame is the world frame; the volume lies within the tile's box
        assert (centre - np.abs(half.reshape(3, 3)).sum(0) >= box[0] - 1e-4).all()
        assert (centre + np.abs(half.reshape(3, 3)).sum(0) <= box[1] + 1e-4).all()
        glb = (tileset / child["content"]["uri"]).read_bytes()
        n = int.from_bytes(glb[12:16], "little")
        gltf = json.loads(glb[20:20 + n])
        assert gltf["nodes"][1]["rotation"] == pytest.approx([-0.5 ** 0.5, 0, 0, 0.5 ** 0.5])   # +z onto +Y
    if VALIDATOR.is_dir() and shutil.which("node"):
        for child in children:
            out = subprocess.run(["node", str(ROOT / "scripts" / "gltf_validate.mjs"),
                                  str(tileset / child["content"]["uri"])], capture_output=True, text=True,
                                 timeout=120)
            assert out.returncode == 0, out.stdout + out.stderr
            report = json.loads(out.stdout)
            assert report["issues"]["numErrors"] == 0, report["issues"]


@pytest.mark.gl
@pytest.mark.slow
def test_two_tiles_meet_without_cracks_and_match_the_field(two_tiles):
    """The tiles drawn together (one depth buffer) at the plan's held-out cameras: no pixel where the field is
    opaque is left empty along the seam, and the frame scores against the field like the tiles' own runs."""
    import torch

    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.tiles import TilesRenderer
    from neuras_distill.render.cameras import Cameras
    from neuras_distill.render.volume import VolumeRenderer
    from neuras_distill.tiles.run import load_plan_source

    city, _ = two_tiles
    plan = json.loads((city / "plan.json").read_text())
    field, _ = load_plan_source(plan)
    cams = Cameras.from_json(json.loads((city / "cameras.json").read_text()))[plan["test"]].resized(192, 108)
    tiles = [load_bundle(city / "tiles" / str(t["index"]) / "tile") for t in plan["tiles"]]
    volume = VolumeRenderer(field, num_steps=plan["settings"]["teacher_steps"])
    with TilesRenderer(tiles) as player:
        for i in range(len(cams)):
            with torch.no_grad():
                want = volume.render(cams, i)
            got = player.render(cams, i)
            ids, depth = player.render_ids(cams, i)
            assert set(np.unique(ids)) == {-1, 0, 1}                      # both tiles in view
            seam = np.zeros(ids.shape, bool)
            seam[:, 1:] |= (ids[:, 1:] != ids[:, :-1]) & (ids[:, 1:] >= 0) & (ids[:, :-1] >= 0)
            near_seam = seam | np.roll(seam, 1, 1) | np.roll(seam, -1, 1) | np.roll(seam, 1, 0) | np.roll(seam, -1, 0)
            rows = np.where(seam.any(1))[0]
            # between the seam's first and last rows, along the seam, every pixel the field covers shows a tile
            span = np.zeros(ids.shape, bool)
            span[rows.min():rows.max() + 1] = True
            holes = (want["opacity"] > 0.99) & (ids < 0) & span & (np.abs(np.arange(ids.shape[1])
                                                                        - np.where(seam)[1].mean()) < 4)[None]
            assert holes.sum() == 0, f"view {i}: {holes.sum()} empty pixels along the seam"
            mse = float(np.mean((got - np.clip(want["rgb"], 0, 1)) ** 2))
            assert -10 * np.log10(mse) >= 26.0, f"view {i}: {-10 * np.log10(mse):.2f} dB against the field"
            assert near_seam.any()


TILES_RENDERER = ROOT / ".tools" / "node_modules" / "3d-tiles-renderer"
THREE = ROOT / ".tools" / "node_modules" / "three"


@pytest.mark.gl
@pytest.mark.slow
def test_the_3dtiles_page_streams_the_tileset_as_the_tiles_renderer_draws_it(two_tiles, browser, http_root, tmp_path):
    """export --format 3dtiles: 3DTilesRendererJS with three.js and our plugin, in headless Chromium, at the plan's
    held-out cameras against TilesRenderer drawing the same tiles; no error or warning on the console."""
    from test_web import wait_for_player

    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.tiles import TilesRenderer
    from neuras_distill.render.cameras import Cameras

    if not (TILES_RENDERER / "build" / "index.three.js").is_file() or not THREE.is_dir():
        pytest.skip("npm's three and 3d-tiles-renderer are not in .tools/ (scripts/setup.sh installs them)")
    city, tileset = two_tiles
    root, base = http_root
    page = root / "tiles-page"
    assert main(["export", str(tileset), "--format", "3dtiles", "--three", str(THREE), "--tiles-renderer",
                 str(TILES_RENDERER), "--out", str(page)]) == 0
    cams = Cameras.from_json(json.loads((tileset / "cameras.json").read_text())["test"])
    plan = json.loads((city / "plan.json").read_text())
    tiles = [load_bundle(city / "tiles" / str(t["index"]) / "tile") for t in plan["tiles"]]
    scores = []
    browser.get_log("browser")
    with TilesRenderer(tiles) as player:
        for i in range(min(3, len(cams))):
            browser.get(f"{base}/tiles-page/index.html?camera={i}")
            shot = wait_for_player(browser)
            stats = browser.execute_script("return window.neurasStats;")
            want = np.round(player.render(cams, i) * 255).astype(np.uint8)
            assert shot.shape == want.shape
            scores.append(float(10 * np.log10(255 ** 2 / max(np.mean((shot.astype(float) - want) ** 2), 1e-9))))
            assert stats["tiles"] >= 1 and stats["bytes"] > 0 and stats["total_tiles"] == 2
    # 3DTilesRendererJS 0.5.3 notes on every 1.1 tileset that its 1.1 support is partial; nothing else is said
    notice = "tiles versions at 1.1 or higher have limited support"
    logged = [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "WARNING")
              and notice not in e["message"]]
    print("tiles page vs TilesRenderer (dB):", scores)
    assert logged == [], logged
    assert min(scores) >= 38.0, scores
    # a folder that is not a tileset of ours: one line, nothing written
    with pytest.raises(BadInputError, match="is not a tileset folder of ours"):
        from neuras_distill.export.tiles_page import export_3dtiles

        export_3dtiles(city, tmp_path / "page", THREE, TILES_RENDERER)
    assert not (tmp_path / "page").exists()


def test_the_tileset_marker_is_the_one_the_page_export_checks():
    from neuras_distill.export.tiles_page import TILESET_MARKER
    from neuras_distill.tiles.tileset import MARKER

    assert TILESET_MARKER == MARKER


def test_a_projected_crs_places_the_tileset_on_the_globe_as_pyproj_does():
    """tiles/crs.py: the root transform is pyproj's ECEF at the scene's centre (to 1 cm; it is exact there), a point
    600 m away is off by the Earth's curvature (about 2.8 cm), and a tile's own transform brings its corners within
    a millimetre."""
    pytest.importorskip("pyproj")
    from neuras_distill.tiles.crs import ecef_points, placement_error, projected_crs, root_transform

    crs = projected_crs("EPSG:32633")
    centre = np.array([5.0e5, 4.2e6, 50.0])
    frame = np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])          # any rigid tileset frame
    root = root_transform(crs, centre, frame)
    assert np.linalg.norm(root[:3, :3] @ (frame @ centre) + root[:3, 3] - ecef_points(crs, centre[None])[0]) < 0.01
    far = placement_error(crs, root, frame, centre + np.array([[600.0, 0, 0], [0, 600.0, 0]]))
    assert 0.02 < far.max() < 0.04
    tile_centre = centre + np.array([450.0, -300.0, 0.0])
    own = root_transform(crs, tile_centre, frame)
    corners = tile_centre + np.array([[sx * 75.0, sy * 75.0, sz * 20.0] for sx in (-1, 1) for sy in (-1, 1)
                                      for sz in (-1, 1)])
    assert placement_error(crs, own, frame, corners).max() < 0.001
    assert placement_error(crs, root, frame, corners).max() > 0.01


@pytest.mark.parametrize("crs, fragment", [("EPSG:4326", "is not a projected CRS"),
                                           ("EPSG:999999", "is not a coordinate reference system PROJ knows")])
def test_an_unknown_or_unprojected_crs_is_one_line_and_writes_nothing(tmp_path, capsys, crs, fragment):
    pytest.importorskip("pyproj")
    city = tmp_path / "city"
    assert _plan(city, "1.5", "--steps", "10") == 0
    capsys.readouterr()
    assert main(["tiles", "merge", str(city), "--out", str(tmp_path / "tileset"), "--crs", crs]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert not (tmp_path / "tileset").exists()


@pytest.mark.gl
@pytest.mark.slow
def test_merge_with_a_crs_writes_the_root_and_tile_transforms(two_tiles, tmp_path):
    pytest.importorskip("pyproj")
    from neuras_distill.tiles.crs import placement_error, projected_crs

    city, _ = two_tiles
    out = tmp_path / "placed"
    assert main(["tiles", "merge", str(city), "--out", str(out), "--crs", "EPSG:32633"]) == 0
    doc = json.loads((out / "tileset.json").read_text())
    root = np.asarray(doc["root"]["transform"]).reshape(4, 4).T
    frame = np.asarray(doc["asset"]["extras"]["neuras_world_to_tileset"])
    crs = projected_crs(doc["asset"]["extras"]["neuras_crs"])
    plan = json.loads((city / "plan.json").read_text())
    for tile, child in zip(plan["tiles"], doc["root"]["children"]):
        own = root @ np.asarray(child["transform"]).reshape(4, 4).T
        corners = np.asarray(tile["box"], np.float64)             # (2, 3): the tile box's lowest and highest corner
        assert placement_error(crs, own, frame, corners).max() < 0.001


@pytest.mark.gl
@pytest.mark.slow
def test_a_maintained_reader_reads_the_tileset_back(two_tiles):
    """PyPI's py3dtiles reads tileset.json and every tile's glb without error (in its own process: it brings
    numba's LLVM, which is kept apart from Mesa's)."""
    pytest.importorskip("py3dtiles")
    _, tileset = two_tiles
    code = ("import sys, json; from pathlib import Path; from py3dtiles.tileset.tileset import TileSet; "
            "root = Path(sys.argv[1]); ts = TileSet.from_file(root / 'tileset.json'); "
            "kids = ts.root_tile.children; "
            "print(json.dumps([[t.content_uri.as_posix(), type(t.get_or_fetch_content(root)).__name__] for t in kids]))")
    out = subprocess.run([sys.executable, "-c", code, str(tileset)], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout.strip().splitlines()[-1]) == [["tiles/0.glb", "Gltf"], ["tiles/1.glb", "Gltf"]]


@pytest.fixture(scope="session")   # one build: its file is one xdist group (conftest.py)
def leveled_tiles(tmp_path_factory):
    """The blocks scene in 2 tiles at 3 levels of detail, run and merged; (city folder, tileset folder)."""
    city = tmp_path_factory.mktemp("levels") / "city"
    assert _plan(city, "1.5", "--steps", "600", "--levels", "3") == 0
    assert main(["tiles", "run", str(city), "--quiet"]) == 0
    assert main(["tiles", "merge", str(city), "--out", str(city / "tileset")]) == 0
    return city, city / "tileset"


@pytest.mark.gl
@pytest.mark.slow
def test_levels_of_detail_have_fewer_faces_and_a_measured_growing_error(leveled_tiles):
    city, tileset = leveled_tiles
    doc = json.loads((tileset / "tileset.json").read_text())
    for k, top in enumerate(doc["root"]["children"]):
        record = json.loads((city / "tiles" / str(k) / "tile.json").read_text())
        levels = record["levels"]
        assert [lv["level"] for lv in levels] == [1, 2]
        assert levels[0]["faces"] > levels[1]["faces"] and levels[0]["side"] > levels[1]["side"]
        assert 0 < levels[0]["error_m"] <= levels[1]["error_m"]
        # the chain: coarsest first, each refined by the next finer, full detail last with error 0
        chain, node = [], top
        while True:
            chain.append((node["content"]["uri"], node["geometricError"], node.get("refine")))
            if not node.get("children"):
                break
            node = node["children"][0]
        assert chain == [(f"tiles/{k}_2.glb", levels[1]["error_m"], "REPLACE"),
                         (f"tiles/{k}_1.glb", levels[0]["error_m"], "REPLACE"), (f"tiles/{k}.glb", 0.0, None)]
        for uri, _, _ in chain:
            assert (tileset / uri).is_file()


@pytest.mark.gl
@pytest.mark.slow
def test_the_page_picks_levels_by_screen_error_as_the_tiles_renderer_draws_them(leveled_tiles, browser, http_root,
                                                                                tmp_path):
    """At the default 16 px target the page draws full detail from a held-out camera and coarse levels from the
    same camera 6 times as far: against TilesRenderer drawing those levels >= 38 dB, against full detail >= 35 dB,
    and from afar it fetched fewer bytes than the whole tileset."""
    import torch

    from test_web import wait_for_player

    from neuras_distill.bake.bundle import load_bundle
    from neuras_distill.playback.tiles import TilesRenderer
    from neuras_distill.render.cameras import Cameras
    from neuras_distill.tiles.levels import level_folder

    if not (TILES_RENDERER / "build" / "index.three.js").is_file() or not THREE.is_dir():
        pytest.skip("npm's three and 3d-tiles-renderer are not in .tools/ (scripts/setup.sh installs them)")
    city, built = leveled_tiles
    tileset = tmp_path / "tileset"
    shutil.copytree(built, tileset)
    near = Cameras.from_json(json.loads((tileset / "cameras.json").read_text())["test"])[0].resized(480)
    c2w = near.c2w.clone()
    centre = torch.tensor(json.loads((city / "plan.json").read_text())["scene_box"]).mean(0)
    c2w[:, :3, 3] = centre + 6.0 * (c2w[:, :3, 3] - centre)            # back along the line to the scene's centre
    cams = near.joined(Cameras(c2w, near.fx, near.fy, near.cx, near.cy, near.width, near.height))
    (tileset / "cameras.json").write_text(json.dumps({"train": cams.to_json(), "test": cams.to_json()}))
    whole = sum(p.stat().st_size for p in (tileset / "tiles").glob("*.glb"))
    root, base = http_root
    assert main(["export", str(tileset), "--format", "3dtiles", "--three", str(THREE), "--tiles-renderer",
                 str(TILES_RENDERER), "--out", str(root / "levels-page")]) == 0

    def bundle_of(uri: str):
        k, _, level = uri.split("/")[-1][:-4].partition("_")
        return load_bundle(level_folder(city, int(level or 0), int(k)) / "tile")

    def score(a, b) -> float:
        return float(10 * np.log10(255 ** 2 / max(np.mean((a.astype(float) - b) ** 2), 1e-9)))

    seen = {}
    with TilesRenderer([bundle_of("tiles/0.glb"), bundle_of("tiles/1.glb")]) as full:
        for view, name in enumerate(("near", "far")):
            browser.get(f"{base}/levels-page/index.html?camera={view}")
            shot = wait_for_player(browser)
            stats = browser.execute_script("return window.neurasStats;")
            with TilesRenderer([bundle_of(u) for u in stats["visible"]], ctx=full.ctx) as same:
                want = np.round(same.render(cams, view) * 255)
            ref = np.round(full.render(cams, view) * 255)
            seen[name] = dict(stats, same_db=score(shot, want), full_db=score(shot, ref))
    print("levels page:", seen, "whole tileset bytes:", whole)
    assert seen["near"]["visible"] == ["tiles/0.glb", "tiles/1.glb"]
    assert seen["far"]["visible"] and all("_" in u for u in seen["far"]["visible"]), seen["far"]
    for name in ("near", "far"):
        assert seen[name]["same_db"] >= 38.0 and seen[name]["full_db"] >= 35.0, seen
    assert seen["far"]["bytes"] < whole


CESIUM = ROOT / ".tools" / "cesium" / "node_modules" / "cesium"


@pytest.mark.gl
@pytest.mark.slow
def test_cesium_shows_the_tileset_at_its_place_on_the_globe(two_tiles, browser, http_root, tmp_path):
    """A tileset merged with --crs EPSG:32633, in CesiumJS in headless Chromium: every tile loads and draws, the root
    transform's ECEF position is pyproj's to 1 cm, and the console holds no error or warning."""
    import base64
    import io
    import time

    from PIL import Image

    pytest.importorskip("pyproj")
    from neuras_distill.tiles.crs import ecef_points, projected_crs

    if not (CESIUM / "Build" / "Cesium" / "Cesium.js").is_file() or not (TILES_RENDERER / "build").is_dir():
        pytest.skip("npm's cesium and 3d-tiles-renderer are not in .tools/ (scripts/setup.sh installs them)")
    city, _ = two_tiles
    placed = tmp_path / "placed"
    assert main(["tiles", "merge", str(city), "--out", str(placed), "--crs", "EPSG:32633"]) == 0
    root, base = http_root
    assert main(["export", str(placed), "--format", "3dtiles", "--three", str(THREE), "--tiles-renderer",
                 str(TILES_RENDERER), "--cesium", str(CESIUM), "--out", str(root / "globe")]) == 0
    browser.get_log("browser")
    browser.get(f"{base}/globe/cesium.html")
    deadline = time.monotonic() + 240
    while True:
        ready, error = browser.execute_script("return [window.neurasReady === true, window.neurasError || null];")
        assert error is None, error
        if ready:
            break
        assert time.monotonic() < deadline, "CesiumJS did not load the tileset in 240 s"
        time.sleep(0.5)
    stats = browser.execute_script("return window.neurasStats;")
    shot = browser.execute_script("return window.neurasCanvas.toDataURL('image/png');")
    img = np.asarray(Image.open(io.BytesIO(base64.b64decode(shot.split(",", 1)[1]))).convert("RGB"))
    Image.fromarray(img).save(tmp_path / "cesium.png")
    plan = json.loads((city / "plan.json").read_text())
    centre = np.asarray(plan["scene_box"], np.float64).mean(0)
    doc = json.loads((placed / "tileset.json").read_text())
    transform = np.asarray(doc["root"]["transform"]).reshape(4, 4).T
    frame = np.asarray(doc["asset"]["extras"]["neuras_world_to_tileset"])
    expected = ecef_points(projected_crs("EPSG:32633"), centre[None])[0]
    # the root transform maps the scene's centre (tileset frame) onto pyproj's ECEF of it; Cesium holds that transform
    assert np.linalg.norm(transform[:3, :3] @ (frame @ centre) + transform[:3, 3] - expected) < 0.01
    assert np.allclose(stats["root_ecef"], transform[:3, 3], atol=0.01)
    assert np.linalg.norm(np.asarray(stats["sphere_centre"]) - expected) < 2.0      # the tiles' bounds around it
    colours = img.reshape(-1, 3)
    globe = np.array([0x2F, 0x4F, 0x6F])
    assert (np.abs(colours.astype(int) - globe).sum(1) > 60).mean() > 0.01, "no tile drawn over the globe"
    logged = [e for e in browser.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]
    assert logged == [], logged
    print("cesium:", stats, "picture:", tmp_path / "cesium.png")
