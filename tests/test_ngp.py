"""Instant-NGP snapshots: frames, container, parameter slicing, forward model, occupancy, bad input.

Snapshots are written by :func:`make_snapshot` from the format description (docs/formats.md §1); the
hash grid itself is checked against a brute-force loop in test_tcnn.py.
"""

from __future__ import annotations

import gzip
import json
import math
import random
import zlib

import msgpack
import numpy as np
import pytest
import torch

from neuras_distill.components.tcnn import HashGridConfig, HashGridEncoding, mlp_param_count, sh_encode_deg4
from neuras_distill.errors import BadInputError
from neuras_distill.render.cameras import Cameras
from neuras_distill_adapters.instant_ngp import InstantNGPAdapter
from neuras_distill_adapters.instant_ngp.field import NgpField
from neuras_distill_adapters.instant_ngp.frames import NgpFrame
from neuras_distill_adapters.instant_ngp.snapshot import (GRID_SIZE, NgpCamera, build_snapshot_tree, morton3d,
                                                          morton_to_xyz, read_snapshot, write_snapshot,
                                                          xyz_to_morton)

SMALL_GRID = HashGridConfig(n_levels=4, n_features_per_level=4, log2_hashmap_size=10, base_resolution=8,
                            per_level_scale=2.0)


def make_tree(*, grid=SMALL_GRID, aabb_scale=1, n_extra=0, seed=0, density_grid=None, cameras=None,
              rgb_alignment=16, **kw):
    rng = np.random.default_rng(seed)
    n_in_d = max(16, grid.n_output_dims())
    dn = mlp_param_count(n_in_d, 64, 1, 16)
    dir_pad = 16 * math.ceil((16 + n_extra) / 16)
    rn = mlp_param_count(16 + dir_pad, 64, 2, 3, output_alignment=rgb_alignment)
    extra = rng.normal(size=(3, n_extra)).astype(np.float32) if n_extra else None
    tree = build_snapshot_tree(grid=grid, density_params=rng.normal(size=dn) * 0.2,
                               rgb_params=rng.normal(size=rn) * 0.2, grid_params=rng.normal(size=grid.n_params()),
                               aabb_scale=aabb_scale, density_grid=density_grid, cameras=cameras,
                               n_extra_dims=n_extra, extra_dims=extra, **kw)
    return tree


def save(tree, path, compress=True):
    return write_snapshot(path, tree, compress=compress)


# ------------------------------------------------------------------------------------------- frames
def test_frame_matches_the_reference_formula():
    frame = NgpFrame(scale=0.33, offset=(0.5, 0.6, 0.7))
    p = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64)
    # p_ngp = cyc(p * s + o), cyc(a, b, c) = (b, c, a)
    want = torch.tensor([[2 * 0.33 + 0.6, 3 * 0.33 + 0.7, 1 * 0.33 + 0.5]], dtype=torch.float64)
    assert torch.allclose(frame.world_to_ngp(p), want)
    assert torch.allclose(frame.ngp_to_world(want), p)
    net = NgpFrame(scale=0.33, offset=(0.5, 0.5, 0.5), aabb_scale=4).world_to_net(torch.zeros(1, 3))
    assert torch.allclose(net, torch.full((1, 3), (0.5 - (0.5 - 2.0)) / 4.0))


def test_fox_cameras_round_trip_through_ngp_space(fox_transforms):
    cams = Cameras.from_transforms(fox_transforms, warn=lambda *_: None)
    meta = json.loads(fox_transforms.read_text())
    frame = NgpFrame(scale=meta.get("scale", 0.33), offset=tuple(meta.get("offset", (0.5, 0.5, 0.5))),
                     aabb_scale=meta["aabb_scale"])
    for i in range(len(cams)):
        c2w = cams.c2w[i].double().numpy()
        m_ngp = frame.world_c2w_to_ngp(c2w)
        # the ngp camera centre is the mapped world centre; ngp camera z (forward) is the mapped world -z
        centre = frame.world_to_ngp(torch.from_numpy(c2w[:3, 3])[None])[0].numpy()
        assert np.allclose(m_ngp[:, 3], centre, atol=1e-9)
        fwd = frame.world_dirs_to_ngp(torch.from_numpy(-c2w[:3, 2])[None])[0].numpy()
        assert np.allclose(m_ngp[:, 2], fwd, atol=1e-9)
        down = frame.world_dirs_to_ngp(torch.from_numpy(-c2w[:3, 1])[None])[0].numpy()
        assert np.allclose(m_ngp[:, 1], down, atol=1e-9)
        assert np.allclose(frame.ngp_c2w_to_world(m_ngp), c2w, atol=1e-9)
    # rays: a world ray maps to the ngp ray of the same pixel
    d = cams.rays(0)[1].reshape(-1, 3)
    m = frame.world_c2w_to_ngp(cams.c2w[0].double().numpy())
    u, v = 100, 200
    k = v * cams.width + u
    cam_dir = np.array([(u + 0.5 - float(cams.cx[0])) / float(cams.fx[0]),
                        (v + 0.5 - float(cams.cy[0])) / float(cams.fy[0]), 1.0])  # ngp: y down, z forward
    d_ngp = m[:, :3] @ cam_dir
    d_ngp /= np.linalg.norm(d_ngp)
    assert np.allclose(frame.world_dirs_to_ngp(d[k:k + 1].double())[0].numpy(), d_ngp, atol=1e-5)


def test_mitsuba_frame_keeps_axes():
    frame = NgpFrame(scale=0.66, offset=(0.165, 0.165, 0.165), from_mitsuba=True)
    p = torch.tensor([[1.0, -2.0, 0.5]], dtype=torch.float64)
    assert torch.allclose(frame.world_to_ngp(p), p * 0.66 + 0.165)
    c2w = np.eye(4)
    c2w[:3, 3] = [1, 2, 3]
    assert np.allclose(frame.ngp_c2w_to_world(frame.world_c2w_to_ngp(c2w)), c2w)


# ------------------------------------------------------------------------------------------- container
def test_morton_order_matches_tcnn():
    assert int(morton3d(np.array(1), np.array(0), np.array(0))) == 1
    assert int(morton3d(np.array(0), np.array(1), np.array(0))) == 2
    assert int(morton3d(np.array(0), np.array(0), np.array(1))) == 4
    assert int(morton3d(np.array(3), np.array(3), np.array(3))) == 63
    assert int(morton3d(np.array(2), np.array(0), np.array(0))) == 8
    grid = np.random.default_rng(0).normal(size=(2, GRID_SIZE, GRID_SIZE, GRID_SIZE)).astype(np.float32)
    m = xyz_to_morton(grid)
    assert m[0, 1] == grid[0, 1, 0, 0] and m[1, 2] == grid[1, 0, 1, 0] and m[0, 4] == grid[0, 0, 0, 1]
    assert np.array_equal(morton_to_xyz(m), grid)


@pytest.mark.parametrize("compress", [True, False])
def test_snapshot_round_trip(tmp_path, compress):
    cams = [NgpCamera(np.hstack([np.eye(3), [[0.1 * i], [0.5], [-0.8]]]), 120.0, 121.0, 64.0, 40.0, 128, 80)
            for i in range(3)]
    dg = np.zeros((1, GRID_SIZE, GRID_SIZE, GRID_SIZE), np.float32)
    dg[0, 10:20, 30:40, 50:60] = 0.5
    tree = make_tree(density_grid=dg, cameras=cams, background_color=(1.0, 1.0, 1.0, 1.0))
    path = save(tree, tmp_path / ("a.ingp" if compress else "a.msgpack"), compress)
    assert path.read_bytes()[:2] == (b"\x1f\x8b" if compress else path.read_bytes()[:2])
    snap = read_snapshot(path)
    blob = np.frombuffer(tree["snapshot"]["params_binary"], "<f2").astype(np.float32)
    d, r = snap.density_mlp.n_params, snap.rgb_mlp.n_params
    assert d == 16 * 64 + 16 * 64 and r == 32 * 64 + 64 * 64 + 16 * 64
    assert np.array_equal(np.concatenate([snap.density_params, snap.rgb_params, snap.grid_params]), blob)
    assert snap.grid.n_params() == snap.grid_params.size
    assert np.array_equal(snap.density_grid, dg.astype(np.float16).astype(np.float32))
    field = NgpField(snap)
    frame = field.frame
    for i, c in enumerate(cams):
        assert np.allclose(frame.world_c2w_to_ngp(field.cameras.c2w[i].double().numpy()), c.c2w_ngp, atol=1e-5)
    assert float(field.cameras.fx[0]) == 120.0 and float(field.cameras.cy[0]) == 40.0
    assert field.background_color.tolist() == [1.0, 1.0, 1.0]


def test_file_extension_does_not_matter(tmp_path):
    from neuras_distill.registry import load_field

    path = save(make_tree(), tmp_path / "weights.bin")
    assert isinstance(load_field(path), NgpField)
    raw = save(make_tree(), tmp_path / "other.dat", compress=False)
    assert isinstance(load_field(raw), NgpField)


def test_adapter_sniffs_snapshots_by_content(tmp_path):
    sniff = InstantNGPAdapter().sniff
    assert sniff(save(make_tree(), tmp_path / "a.bin"))
    assert sniff(save(make_tree(), tmp_path / "b.dat", compress=False))
    zlib_path = tmp_path / "c.msgpack"
    zlib_path.write_bytes(zlib.compress(msgpack.packb(make_tree(), use_bin_type=True)))
    assert sniff(zlib_path)
    for what, data in _bad_files(tmp_path).items():
        if what in ("random bytes", "empty", "3dgrut"):
            (tmp_path / "x.ingp").write_bytes(data)
            assert not sniff(tmp_path / "x.ingp"), what
    assert not sniff(tmp_path / "missing.ingp") and not sniff(tmp_path)


# ------------------------------------------------------------------------------------------- forward model
def _reference_forward(tree, x_world, d_world, frame, n_extra=0, latent=None):
    """The forward model written out from the format description with plain matrix products."""
    snap = tree["snapshot"]
    p = np.frombuffer(snap["params_binary"], "<f2").astype(np.float64)
    grid = SMALL_GRID
    dn = mlp_param_count(16, 64, 1, 16)
    dir_pad = 16 * math.ceil((16 + n_extra) / 16)
    w0 = p[:64 * 16].reshape(64, 16)
    w1 = p[64 * 16:dn].reshape(16, 64)
    q = p[dn:]
    rin = 16 + dir_pad
    r0 = q[:64 * rin].reshape(64, rin)
    r1 = q[64 * rin:64 * rin + 64 * 64].reshape(64, 64)
    r2 = q[64 * rin + 64 * 64:64 * rin + 64 * 64 + 16 * 64].reshape(16, 64)
    table = q[64 * rin + 64 * 64 + 16 * 64:]
    enc = HashGridEncoding(grid, torch.from_numpy(table).float())
    x_net = frame.world_to_net(x_world.double()).float()
    e = enc(x_net).detach().double().numpy()
    h = np.maximum(e @ w0.T, 0) @ w1.T
    sigma = np.exp(h[:, 0]) * frame.scale
    d_ngp = frame.world_dirs_to_ngp(d_world.double()).float()
    sh = sh_encode_deg4(d_ngp).double().numpy()
    parts = [h, sh]
    if n_extra:
        parts.append(np.repeat(latent[None].astype(np.float64), len(h), 0))
    width = sum(a.shape[1] for a in parts)
    parts.append(np.ones((len(h), rin - width)))
    z = np.concatenate(parts, axis=1)
    v = np.maximum(np.maximum(z @ r0.T, 0) @ r1.T, 0) @ r2.T
    return sigma, 1 / (1 + np.exp(-v[:, :3]))


@pytest.mark.parametrize("n_extra", [0, 3])
def test_forward_model_matches_the_format_description(tmp_path, n_extra, one_torch_thread):
    tree = make_tree(n_extra=n_extra, scale=0.5, offset=(0.5, 0.4, 0.45))
    field = NgpField(read_snapshot(save(tree, tmp_path / "f.ingp")))
    assert field.rgb_mlp_in == 16 + (16 if n_extra == 0 else 32)  # density outputs + padded SH/latent
    gen = torch.Generator().manual_seed(1)
    x = field.aabb[0] + torch.rand(500, 3, generator=gen) * (field.aabb[1] - field.aabb[0])
    d = torch.nn.functional.normalize(torch.randn(500, 3, generator=gen), dim=-1)
    latent = None
    if n_extra:
        latent = np.asarray(tree["snapshot"]["nerf"]["extra_dims_opt"][0]["variable"], np.float32)
    sigma, rgb = _reference_forward(tree, x, d, field.frame, n_extra, latent)
    assert np.allclose(field.geometry(x).numpy(), sigma, rtol=1e-4, atol=1e-6)
    assert np.allclose(field.radiance(x, d).numpy(), rgb, atol=1e-5)


def test_cutlass_alignment_8_is_recognised_by_the_parameter_count(tmp_path):
    snap = read_snapshot(save(make_tree(rgb_alignment=8), tmp_path / "c.ingp"))
    assert snap.cutlass_alignment_8 and snap.rgb_mlp.output_alignment == 8
    assert any("CutlassMLP" in n for n in snap.notes)


def test_fp32_params_and_missing_per_level_scale(tmp_path):
    grid = HashGridConfig(n_levels=4, n_features_per_level=4, log2_hashmap_size=10, base_resolution=8,
                          per_level_scale=float(np.float32(np.exp(np.log(2048 * 2 / 8) / 3))))
    tree = make_tree(grid=grid, aabb_scale=2, params_type="float", write_per_level_scale=False)
    assert "per_level_scale" not in tree["encoding"]
    snap = read_snapshot(save(tree, tmp_path / "g.ingp"))
    assert snap.params_type == "float"
    assert snap.grid.per_level_scale == pytest.approx(grid.per_level_scale, rel=1e-6)


def test_hdr_snapshot_is_displayed_like_instant_ngp(tmp_path):
    tree = make_tree(is_hdr=True)
    tree["snapshot"]["exposure"] = 1.0
    hdr = NgpField(read_snapshot(save(tree, tmp_path / "h.ingp")))
    ldr = NgpField(read_snapshot(save(make_tree(), tmp_path / "l.ingp")))
    x = torch.zeros(4, 3) + hdr.aabb.mean(0)
    d = torch.nn.functional.normalize(torch.randn(4, 3, generator=torch.Generator().manual_seed(0)), dim=-1)
    v = torch.logit(ldr.radiance(x, d).double(), eps=0)  # the raw rgb output
    lin = (torch.exp(v.clamp(-10, 10)) * 2.0).clamp(0, 1)
    srgb = torch.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    assert torch.allclose(hdr.radiance(x, d).double(), srgb, atol=1e-4)


# ------------------------------------------------------------------------------------------- occupancy and boxes
def test_density_grid_gates_the_field_and_bounds_the_box(tmp_path, one_torch_thread):
    dg = np.full((1, GRID_SIZE, GRID_SIZE, GRID_SIZE), -1.0, np.float32)
    dg[0, 40:80, 50:70, 60:100] = 1.0
    field = NgpField(read_snapshot(save(make_tree(density_grid=dg), tmp_path / "o.ingp")))
    # the foreground box is the occupied cells (ngp box 40/128..80/128 etc.) dilated by two cells, in world
    lo_ngp = (np.array([40, 50, 60]) - 2) / GRID_SIZE
    hi_ngp = (np.array([80, 70, 100]) + 2) / GRID_SIZE
    want = field.frame.ngp_box_to_world(lo_ngp.tolist(), hi_ngp.tolist())
    assert torch.allclose(field.aabb, want, atol=1e-5)
    assert not field.unbounded
    gen = torch.Generator().manual_seed(0)
    x = field.aabb[0] + torch.rand(20000, 3, generator=gen) * (field.aabb[1] - field.aabb[0])
    p = field.frame.world_to_ngp(x)
    cell = (p * GRID_SIZE).floor().long()
    inside = ((cell >= torch.tensor([40, 50, 60])) & (cell < torch.tensor([80, 70, 100]))).all(1)
    sigma = field.geometry(x)
    assert bool((sigma[~inside] == 0).all()) and bool((sigma[inside] > 0).all())
    occ = field.occupancy_grid(64)
    assert bool(occ.query(x[inside]).all())  # conservative: every occupied point is in an occupied cell
    assert occ.fraction < 0.85  # the occupied block fills 69% of its dilated box


def test_large_aabb_scale_foreground_box_and_unbounded_flag(tmp_path):
    dg = np.zeros((3, GRID_SIZE, GRID_SIZE, GRID_SIZE), np.float32)  # aabb_scale 4 -> cascades 0, 1, 2
    dg[0, 60:70, 60:70, 60:70] = 1.0   # an object in the middle of the unit cube
    dg[2, 0:5, :, :] = 1.0            # far content (cascade 2 spans [-1.5, 2.5])
    grid = HashGridConfig(n_levels=4, n_features_per_level=4, log2_hashmap_size=10, base_resolution=8,
                          per_level_scale=2.0)
    field = NgpField(read_snapshot(save(make_tree(grid=grid, aabb_scale=4, density_grid=dg), tmp_path / "u.ingp")))
    assert field.unbounded
    ngp_box = field.frame.world_box_to_ngp(field.aabb)
    assert torch.allclose(ngp_box[0].float(), torch.full((3,), 58 / 128), atol=1e-5)
    assert torch.allclose(ngp_box[1].float(), torch.full((3,), 72 / 128), atol=1e-5)
    # far cells are occupied where they are, and found through the coarse cascade
    far = field.frame.ngp_to_world(torch.tensor([[-1.45, 0.5, 0.5]]))
    assert bool(field.occupied(far)[0])
    box = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    override = NgpField(read_snapshot(tmp_path / "u.ingp"), foreground_box=box)
    assert override.aabb.tolist() == box



@pytest.mark.slow
def test_outer_cascades_render_as_a_dense_march_of_the_whole_network_cube(tmp_path):
    """aabb_scale 4 with content in the outer cascades (a wall behind the object): the teacher marches the box and
    the network cube around it (``far_region``) and draws what a dense march of the whole cube draws; clipped to
    the box it misses the wall."""
    from neuras_distill.render.volume import VolumeRenderer

    dg = np.zeros((3, GRID_SIZE, GRID_SIZE, GRID_SIZE), np.float32)   # ngp axes; cascade c spans 0.5 +- 2^(c-1)
    dg[0, 56:72, 56:72, 56:72] = 1.0                                 # the object, in the unit cube's middle
    dg[2, 2:10, 16:112, 16:112] = 1.0                                # a wall near ngp x = -1.3
    grid = HashGridConfig(n_levels=4, n_features_per_level=2, log2_hashmap_size=12, base_resolution=4,
                          per_level_scale=2.0)
    path = save(make_tree(grid=grid, aabb_scale=4, density_grid=dg, seed=3), tmp_path / "u.ingp")
    field = NgpField(read_snapshot(path))
    assert field.unbounded and field.far_region is not None
    frame = field.frame
    cube = frame.ngp_box_to_world([-1.5] * 3, [2.5] * 3)
    whole = NgpField(read_snapshot(path), foreground_box=cube.tolist())      # the whole cube as its box
    assert not whole.unbounded and whole.far_region is None
    eye = frame.ngp_to_world(torch.tensor([[1.8, 0.5, 0.5]], dtype=torch.float64))[0]   # inside cascade 2
    target = frame.ngp_to_world(torch.tensor([[0.5, 0.5, 0.5]], dtype=torch.float64))[0]
    from neuras_distill.render.cameras import look_at
    up = frame.ngp_to_world(torch.tensor([[0.5, 1.5, 0.5]], dtype=torch.float64))[0] - target
    cams = Cameras(look_at(eye, target, up)[None].float(), 15.0, 15.0, 8.0, 6.0, 16, 12)
    reference = VolumeRenderer(whole, num_steps=2048).render(cams, 0)
    teacher = VolumeRenderer(field, num_steps=256, far_steps=512).render(cams, 0)
    clipped = VolumeRenderer(field, num_steps=256, far_steps=0).render(cams, 0)

    def psnr(a, b):
        return float(-10 * np.log10(max(float(np.mean((a - b) ** 2)), 1e-12)))
    wall_share = float(np.mean(np.abs(reference["rgb"] - clipped["rgb"]).max(-1) > 0.05))
    assert wall_share > 0.2                                   # the wall shows in a fifth of the frame or more
    assert psnr(clipped["rgb"], reference["rgb"]) < 25.0      # clipped to the box, it is missing
    assert psnr(teacher["rgb"], reference["rgb"]) > 35.0      # with the far region, it is drawn

# ------------------------------------------------------------------------------------------- bad input
def _cli(args):
    from neuras_distill.cli import main

    return main(args)


def _bad_files(tmp_path):
    good = make_tree()
    files = {}
    files["random bytes"] = random.Random(0).randbytes(5000)
    files["random map-like bytes"] = b"\x85" + random.Random(1).randbytes(5000)  # sniffs as a msgpack map
    full = gzip.compress(msgpack.packb(good, use_bin_type=True))
    files["truncated gzip"] = full[: len(full) // 2]
    files["empty"] = b""
    t = make_tree(); del t["snapshot"]["params_binary"]
    files["no parameters"] = gzip.compress(msgpack.packb(t, use_bin_type=True))
    t = make_tree(); t["snapshot"]["n_params"] = 10**12
    files["absurd count"] = gzip.compress(msgpack.packb(t, use_bin_type=True))
    t = make_tree(); t["encoding"]["log2_hashmap_size"] = 11
    files["count vs config"] = gzip.compress(msgpack.packb(t, use_bin_type=True))
    t = make_tree()
    arr = np.frombuffer(t["snapshot"]["params_binary"], "<f2").copy(); arr[5] = np.nan
    t["snapshot"]["params_binary"] = arr.tobytes()
    files["nan"] = gzip.compress(msgpack.packb(t, use_bin_type=True))
    t = make_tree(); t["snapshot"]["mode"] = "sdf"
    files["sdf mode"] = gzip.compress(msgpack.packb(t, use_bin_type=True))
    t = make_tree(); t["encoding"] = {"otype": "Frequency", "n_frequencies": 12}
    files["frequency encoding"] = gzip.compress(msgpack.packb(t, use_bin_type=True))
    files["3dgrut"] = gzip.compress(msgpack.packb({"nre_data": {"version": 1, "model": "mogt"}, "mog_num": 3,
                                                   "mog_positions": b"\0" * 36}, use_bin_type=True))
    files["zip bomb"] = gzip.compress(b"\x81" + b"\0" * 50_000_000, compresslevel=9)
    return files


EXPECT = {
    "random bytes": "not an Instant-NGP snapshot", "random map-like bytes": "not an Instant-NGP snapshot",
    "truncated gzip": "truncated", "empty": "empty",
    "no parameters": "no parameters", "absurd count": "n_params", "count vs config": "its configuration needs",
    "nan": "NaN", "sdf mode": "'sdf' snapshot", "frequency encoding": "Frequency", "3dgrut": "3DGRUT",
    "zip bomb": "decompresses to more than",
}


def test_bad_snapshots_give_one_clear_line_and_write_nothing(tmp_path, capsys):
    for what, data in _bad_files(tmp_path).items():
        path = tmp_path / f"{what.replace(' ', '_')}.ingp"
        path.write_bytes(data)
        out = tmp_path / f"run_{what.replace(' ', '_')}"
        code = _cli(["from-ngp", str(path), "--out", str(out), "--quiet"])
        err = capsys.readouterr().err.strip()
        assert code == 2, what
        assert len(err.splitlines()) == 1 and "Traceback" not in err, (what, err)
        assert EXPECT[what] in err, (what, err)
        assert not out.exists(), what
        assert not any(p.name.startswith(out.name) for p in tmp_path.iterdir() if p != path), what
    for args, needle in ((["from-ngp", str(tmp_path / "missing.ingp")], "does not exist"),
                         (["from-ngp", str(tmp_path)], "is a directory")):
        assert _cli(args + ["--out", str(tmp_path / "r"), "--quiet"]) == 2
        assert needle in capsys.readouterr().err


def test_grid_size_is_checked_before_allocating():
    with pytest.raises(BadInputError, match="log2_hashmap_size"):
        HashGridConfig.from_json({"otype": "HashGrid", "log2_hashmap_size": 40})
