"""Tests of neuras_distill.neural: bilinear convention, VQ, SSIM/VGG loader, model, fit()."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuras_distill.config import TrainConfig
from neuras_distill.errors import BadInputError
from neuras_distill.neural.convergence import PlateauStop
from neuras_distill.neural.losses import PerceptualLoss, ssim, vgg16_features
from neuras_distill.neural.model import NeuralTextureModel
from neuras_distill.neural.shader import MLPShader
from neuras_distill.neural.texture import NeuralTexture, bilinear_corners
from neuras_distill.neural.train import fit
from neuras_distill.neural.train_batches import TrainingPixels
from neuras_distill.neural.vq import VectorQuantizer


# ------------------------------------------------------------------------------------------ bilinear
def test_bilinear_texel_centre_has_weight_one():
    h, w = 6, 10
    i, j = 3, 4
    idx, wt = bilinear_corners(torch.tensor([[(i + 0.5) / w, (j + 0.5) / h]]), h, w)
    assert idx[0, 0].item() == j * w + i
    assert wt[0, 0].item() == pytest.approx(1.0, abs=1e-6)
    assert wt[0, 1:].abs().max().item() < 1e-6


def test_bilinear_halfway_between_texels():
    h, w = 6, 10
    uv = torch.tensor([[(2 + 1.0) / w, (1 + 0.5) / h],      # between texels (2,1) and (3,1)
                       [(2 + 0.5) / w, (1 + 1.0) / h]])     # between texels (2,1) and (2,2)
    idx, wt = bilinear_corners(uv, h, w)
    assert idx[0].tolist() == [1 * w + 2, 1 * w + 3, 2 * w + 2, 2 * w + 3]
    assert wt[0].tolist() == pytest.approx([0.5, 0.5, 0.0, 0.0], abs=1e-6)
    assert idx[1].tolist() == [1 * w + 2, 1 * w + 3, 2 * w + 2, 2 * w + 3]
    assert wt[1].tolist() == pytest.approx([0.5, 0.0, 0.5, 0.0], abs=1e-6)
    assert torch.allclose(wt.sum(1), torch.ones(2))


def test_bilinear_clamps_at_borders():
    h, w = 4, 5
    idx, wt = bilinear_corners(torch.tensor([[0.0, 0.0], [1.0, 1.0], [-0.3, 1.7]]), h, w)
    assert idx.min().item() >= 0 and idx.max().item() <= h * w - 1
    # uv (0,0): x = y = -0.5, every corner clamps to texel (0,0)
    assert idx[0].tolist() == [0, 0, 0, 0]
    # uv (1,1): all corners clamp to the last texel
    assert idx[1].tolist() == [h * w - 1] * 4
    # far outside: column 0, row H-1
    assert set(idx[2].tolist()) == {(h - 1) * w}
    tex = NeuralTexture(h, w, 3)
    f = (wt[..., None] * tex.flat[idx]).sum(1)
    assert torch.allclose(f[0], tex.data[0, 0]) and torch.allclose(f[1], tex.data[-1, -1])


# ------------------------------------------------------------------------------------------ VQ
def test_vq_assigns_correctly_far_from_origin():
    torch.manual_seed(0)
    k, d = 64, 16
    vq = VectorQuantizer(k, d)
    base = torch.randn(k, d)
    base = base / base.norm(dim=1, keepdim=True)
    vq.codebook.data = 1e3 + 0.01 * base * torch.arange(1, k + 1)[:, None] / k * 4  # codes ~0.01 apart
    codes = vq.codebook.data
    # make sure codes are distinct at the 0.01 scale
    target = torch.randint(0, k, (2000,))
    z = codes[target] + (torch.rand(2000, d) - 0.5) * 2e-4  # within 1e-3 of their code
    vq.eval()
    _, idx, _ = vq(z)
    exact = ((z[:, None, :].double() - codes[None].double()) ** 2).sum(-1).argmin(1)
    assert (idx == exact).float().mean().item() == 1.0
    assert (vq.quantize_all(z, chunk=333) == exact).all()


def test_vq_dead_code_reset_keeps_codes_in_use():
    torch.manual_seed(0)
    k = 16

    def train(dead_after):
        vq = VectorQuantizer(k, 2, dead_after=dead_after)
        vq.codebook.data = torch.randn(k, 2) * 0.01 + 5.0   # all codes far away: collapse without reset
        opt = torch.optim.Adam(vq.parameters(), lr=0.05)
        for _ in range(200):
            z = torch.rand(512, 2)
            _, _, loss = vq(z)
            opt.zero_grad()
            loss.backward()
            opt.step()
        vq.eval()
        return VectorQuantizer.perplexity_of(vq.quantize_all(torch.rand(4096, 2)), k)

    assert train(dead_after=0) < 0.2 * k
    assert train(dead_after=5) >= 0.5 * k


def test_vq_straight_through_and_codebook_loss_decreases():
    torch.manual_seed(0)
    vq = VectorQuantizer(8, 4)
    z0 = torch.randn(256, 4)
    vq.init_from(z0[:32])
    z = z0.clone().requires_grad_(True)
    zq, idx, loss = vq(z)
    assert torch.equal(zq.detach(), vq.codebook.detach()[idx])      # forward value is exactly the code
    (zq * torch.arange(4.0)).sum().backward()
    assert torch.allclose(z.grad, torch.arange(4.0).expand(256, 4))  # identity gradient to z
    vq = VectorQuantizer(8, 4, dead_after=0)        # untrained codebook near the origin
    opt = torch.optim.Adam([vq.codebook], lr=0.02)
    losses = []
    for _ in range(60):
        _, _, loss = vq(z0)
        losses.append(loss.item())
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert losses[-1] < 0.8 * losses[0], (losses[0], losses[-1])


def test_vq_prune_remap():
    vq = VectorQuantizer(6, 2)
    used = torch.tensor([[5, 1], [1, 3]])
    cb, remap = vq.prune(used)
    assert cb.shape == (3, 2)
    assert remap.tolist() == [-1, 0, -1, 1, -1, 2]
    assert torch.equal(cb[remap[used]], vq.codebook.detach()[used])


def test_vq_init_from_kmeans_and_stats():
    torch.manual_seed(0)
    centres = torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    z = centres[torch.randint(0, 4, (400,))] + 0.01 * torch.randn(400, 2)
    vq = VectorQuantizer(4, 2)
    vq.init_from(z)
    vq(z)
    d = torch.cdist(centres, vq.codebook.detach()).min(1).values
    assert d.max().item() < 0.5
    assert vq.perplexity > 3.5 and vq.used_fraction == 1.0


# ------------------------------------------------------------------------------------------ losses
def test_ssim_values():
    torch.manual_seed(0)
    a = torch.rand(2, 3, 16, 16)
    assert ssim(a, a).item() == pytest.approx(1.0, abs=1e-5)
    b = torch.rand(2, 3, 16, 16)
    assert ssim(a, b).item() < 0.2
    noisy = (a + 0.05 * torch.randn_like(a)).clamp(0, 1)
    assert 0.5 < ssim(a, noisy).item() < 1.0
    # masked: only covered window centres count
    mask = torch.zeros(2, 16, 16, dtype=torch.bool)
    mask[:, :8] = True
    c = a.clone()
    c[:, :, 12:] = b[:, :, 12:]
    assert ssim(a, c, mask=mask).item() > ssim(a, c).item()
    x = a.clone().requires_grad_(True)
    (1 - ssim(x, b)).backward()
    assert torch.isfinite(x.grad).all()


def test_perceptual_loss_absent_and_random_state_dict(tmp_path, monkeypatch):
    missing = tmp_path / "nope.pth"
    monkeypatch.setenv("NEURAS_VGG16_WEIGHTS", str(missing))
    ok, reason = PerceptualLoss.available()
    assert not ok and str(missing) in reason and "NEURAS_VGG16_WEIGHTS" in reason
    with pytest.raises(BadInputError):
        PerceptualLoss()
    torch.manual_seed(0)
    state = {f"features.{k}": v for k, v in vgg16_features().state_dict().items()}
    state["classifier.0.weight"] = torch.zeros(4, 4)      # torchvision files carry the classifier too
    path = tmp_path / "vgg16-397923af.pth"
    torch.save(state, path)
    monkeypatch.delenv("NEURAS_VGG16_WEIGHTS")
    monkeypatch.setenv("TORCH_HOME", str(tmp_path.parent / tmp_path.name / "th"))
    (tmp_path / "th" / "hub" / "checkpoints").mkdir(parents=True)
    (tmp_path / "th" / "hub" / "checkpoints" / path.name).write_bytes(path.read_bytes())
    assert PerceptualLoss.available()[0]
    loss = PerceptualLoss()
    assert torch.equal(loss.features[0].weight, state["features.0.weight"])
    a = torch.rand(1, 3, 32, 32)
    assert loss(a, a).item() == 0.0
    assert loss(a, torch.rand(1, 3, 32, 32)).item() > 0.0
    torch.save({"features.0.weight": torch.zeros(3)}, path)
    with pytest.raises(BadInputError):
        PerceptualLoss(path)


# ------------------------------------------------------------------------------------------ model
def test_shader_shapes():
    s = MLPShader(8, hidden=32, num_layers=3, use_viewdir=True, output_layers=1)
    assert [l.weight.shape for l in s.layers] == [(32, 11), (32, 32), (3, 32)]
    out = s(torch.randn(5, 8), torch.randn(5, 3))
    assert out.shape == (5, 3) and out.min() > 0 and out.max() < 1
    assert MLPShader(8, use_viewdir=False).layers[0].in_features == 8


def test_output_layers_are_composited_front_to_back_with_the_last_opaque():
    torch.manual_seed(0)
    s = MLPShader(6, hidden=16, use_viewdir=True, output_layers=3)
    assert s.layers[-1].out_features == 12
    feats, dirs = torch.randn(7, 6), torch.nn.functional.normalize(torch.randn(7, 3), dim=-1)
    raw = s.layers[1](torch.relu(s.layers[0](torch.cat([feats, dirs], -1))))
    c = torch.sigmoid(raw.view(7, 3, 4)[..., :3])
    a = torch.sigmoid(raw.view(7, 3, 4)[..., 3])
    a1, a2 = a[:, 0:1], a[:, 1:2]                               # the third layer's opacity is not used
    expected = a1 * c[:, 0] + (1 - a1) * a2 * c[:, 1] + (1 - a1) * (1 - a2) * c[:, 2]
    assert torch.allclose(s(feats, dirs), expected, atol=1e-6)
    with pytest.raises(ValueError, match="output_layers"):
        MLPShader(6, output_layers=0)


def test_model_quantized_forward_equals_baked_lookup():
    torch.manual_seed(0)
    m = NeuralTextureModel(8, 12, feature_dim=5, num_codes=16)
    m.start_vq()
    m.eval()
    uv = torch.rand(300, 2)
    dirs = torch.nn.functional.normalize(torch.randn(300, 3), dim=1)
    rgb, aux = m(uv, dirs)
    index, codebook = m.baked_features()
    assert index.shape == (8, 12) and codebook.shape[1] == 5 and codebook.shape[0] <= 16
    idx, w = bilinear_corners(uv, 8, 12)
    feats = torch.from_numpy(codebook)[torch.from_numpy(index).view(-1)[idx]]
    f = w[:, 0:1] * feats[:, 0] + w[:, 1:2] * feats[:, 1] + w[:, 2:3] * feats[:, 2] + w[:, 3:4] * feats[:, 3]
    assert torch.equal(m.shader(f, dirs), rgb)


def test_fill_unseen_texels_copies_nearest_touched():
    m = NeuralTextureModel(4, 6, feature_dim=2, use_vq=False)
    mask = np.zeros((4, 6), bool)
    mask[1, 1] = mask[2, 5] = True
    before = m.texture.data.detach().clone()
    assert m.fill_unseen_texels(mask) == 22
    t = m.texture.data.detach()
    assert torch.equal(t[1, 1], before[1, 1]) and torch.equal(t[2, 5], before[2, 5])
    assert torch.equal(t[0, 0], before[1, 1]) and torch.equal(t[3, 5], before[2, 5])


@pytest.mark.parametrize("pages", [1, 2])
def test_coarse_level_adds_its_bilinear_lookup_at_each_texel_centre_and_folds_into_the_atlas(pages):
    """A texel's feature is its own value plus the coarse atlas's bilinear lookup at the texel's centre, within
    the texel's page; folding moves it all into the fine atlas without changing any feature."""
    torch.manual_seed(0)
    tex = NeuralTexture(8 * pages, 8, 3, coarse_factor=4, pages=pages)
    assert tuple(tex.coarse.shape) == (2 * pages, 2, 3) and tex.coarse.abs().max() == 0
    tex.coarse.data.normal_()
    j, i = 1, 6                                       # texel (6, 1): centre uv (6.5/8, 1.5/(8 P))
    uv = torch.tensor([[6.5 / 8, 1.5 / (8 * pages)]])
    cidx, cw = bilinear_corners(uv, 2 * pages, 2, pages)
    expected = tex.data[j, i] + (cw[0, :, None] * tex.coarse.view(-1, 3)[cidx[0]]).sum(0)
    torch.testing.assert_close(tex.gather(torch.tensor([j * 8 + i]))[0], expected)
    if pages == 2:                                    # a texel on the second page reads only its page's coarse rows
        below = tex.gather(torch.tensor([8 * 8 + 0]))[0] - tex.data[8, 0]
        torch.testing.assert_close(below, tex.coarse[2, 0].detach())
    before = tex.features_flat().clone()
    tex.fold_coarse()
    assert tex.coarse.abs().max() == 0
    torch.testing.assert_close(tex.features_flat(), before)


def test_coarse_level_gets_the_gradient_of_its_touched_texels_only():
    tex = NeuralTexture(16, 16, 2, coarse_factor=4)
    rows = tex.gather(torch.tensor([[0, 1, 16, 17]]))          # the four texels of the atlas's corner
    rows.sum().backward()
    assert tex.data.grad.is_sparse and not tex.coarse.grad.is_sparse
    touched = {tuple(ij) for ij in torch.nonzero(tex.coarse.grad.abs().sum(-1)).tolist()}
    assert touched == {(0, 0)}                                  # their centres lie before the first coarse centre
    assert tex.coarse.grad.sum().item() == pytest.approx(4 * 2)  # each texel's coarse weights sum to 1, 2 channels


def test_atlas_gradient_holds_each_texel_once_and_sums_its_lookups():
    """Lookups that share texels (neighbouring pixels' bilinear corners) give one gradient row per texel, in
    order, the sum of its lookups' gradients, as a dense lookup would."""
    torch.manual_seed(0)
    tex = NeuralTexture(8, 8, 3)
    idx = torch.tensor([[9, 10, 17, 18], [10, 11, 18, 19], [63, 9, 9, 0]])
    weights = torch.randn(3, 4, 3)
    (tex.gather(idx) * weights).sum().backward()
    grad = tex.data.grad
    assert grad.is_sparse
    flat = grad._indices()[0] * 8 + grad._indices()[1]
    assert flat.tolist() == sorted(set(idx.flatten().tolist()))
    dense = tex.data.detach().clone().requires_grad_(True)
    (dense.view(-1, 3)[idx] * weights).sum().backward()
    torch.testing.assert_close(grad.to_dense(), dense.grad)


def test_a_model_with_a_coarse_level_bakes_what_it_plays():
    torch.manual_seed(0)
    m = NeuralTextureModel(16, 16, feature_dim=4, num_codes=32, coarse_factor=4)
    m.texture.coarse.data.normal_()
    m.eval()
    uv = torch.rand(200, 2)
    dirs = torch.nn.functional.normalize(torch.randn(200, 3), dim=1)
    with torch.no_grad():
        continuous, _ = m(uv, dirs)
    m.start_vq()                                      # k-means of fine + coarse: the coarse level is folded in
    assert m.texture.coarse.abs().max() == 0
    index, codebook = m.baked_features()
    idx, w = bilinear_corners(uv, 16, 16)
    feats = torch.from_numpy(codebook)[torch.from_numpy(index).view(-1)[idx]]
    f = w[:, 0:1] * feats[:, 0] + w[:, 1:2] * feats[:, 1] + w[:, 2:3] * feats[:, 2] + w[:, 3:4] * feats[:, 3]
    with torch.no_grad():
        played, _ = m(uv, dirs)
    assert torch.equal(m.shader(f, dirs), played)
    assert (played - continuous).abs().max() < 0.1    # 32 codes for 256 texels: close, not exact


# ------------------------------------------------------------------------------------------ fit
def synthetic_gbuffer(n=4, res=32, seed=0):
    """A fake G-buffer: each view sees an affine patch of the atlas; colour analytic in uv and view dir."""
    rng = np.random.default_rng(seed)
    ys, xs = np.meshgrid((np.arange(res) + 0.5) / res, (np.arange(res) + 0.5) / res, indexing="ij")
    uv = np.zeros((n, res, res, 2), np.float32)
    dirs = np.zeros((n, res, res, 3), np.float32)
    cov = np.ones((n, res, res), bool)
    for k in range(n):
        o = rng.uniform(0, 0.2, 2)
        uv[k, ..., 0] = o[0] + 0.8 * xs
        uv[k, ..., 1] = o[1] + 0.8 * (1 - ys)
        d = np.stack([xs - 0.5 + 0.3 * np.cos(k), ys - 0.5 + 0.3 * np.sin(k), -np.ones_like(xs)], -1)
        dirs[k] = d / np.linalg.norm(d, axis=-1, keepdims=True)
        cov[k, :3, :5] = False
    u, v = uv[..., 0], uv[..., 1]
    tgt = np.stack([0.5 + 0.3 * np.sin(6 * u) * np.cos(4 * v), 0.5 + 0.3 * np.cos(5 * v + u),
                    0.4 + 0.2 * u + 0.2 * v], -1) + 0.05 * dirs[..., 0:1]
    return uv, cov, dirs, tgt.astype(np.float32)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _psnr(model, uv, cov, dirs, tgt):
    vals = []
    for k in range(uv.shape[0]):
        img = model.render_gbuffer(uv[k], cov[k], dirs[k], np.zeros(3))
        vals.append(-10 * np.log10(((img - tgt[k])[cov[k]] ** 2).mean()))
    return float(np.mean(vals))


def test_fit_reaches_psnr_on_smooth_target():
    torch.manual_seed(0)
    data = synthetic_gbuffer()
    model = NeuralTextureModel(32, 32, feature_dim=8, num_codes=256, use_vq=True)
    start = _psnr(model, *data)
    log = fit(model, TrainingPixels(*data), steps=250, config=TrainConfig(batch_patches=8, patch=16, vq_warmup=0.15),
              progress=False, log_every=25, num_threads=1)
    end = _psnr(model, *data)
    assert start < 20 and end > 30, (start, end)
    assert log.steps == 250 and log.stopped_by == "steps"
    assert log.vq_start_step is not None and 0 < log.vq_start_step < 100
    assert log.vq_stats["used_fraction"] > 0.5
    assert [e["step"] for e in log.entries][-1] == 250
    assert all({"step", "seconds", "loss", "psnr"} <= set(e) for e in log.entries)
    assert 0 < log.touched_fraction < 1 and log.filled_texels > 0
    assert not model.training


@pytest.mark.slow
def test_fit_quantizes_after_training_by_default():
    """Default schedule: continuous features all along, k-means codes after the last step. On the same data
    and seed it beats quantizing from 15 % of the run (measured 34.7 vs 33.7 dB with 64 codes and the
    default 32-wide shader; 33.7 vs 29.7 at 16 wide), and the code stats come from the texels' assignments."""
    def trained(**kwargs):
        torch.manual_seed(0)
        data = synthetic_gbuffer()
        model = NeuralTextureModel(32, 32, feature_dim=8, num_codes=64, use_vq=True, quantize_above=0)
        log = fit(model, TrainingPixels(*data), steps=250, config=TrainConfig(batch_patches=8, patch=16, **kwargs), progress=False,
                  num_threads=1)
        return model, log, _psnr(model, *data)

    model, log, after = trained()
    _, early_log, early = trained(vq_warmup=0.15)
    assert log.vq_start_step == 250 and model.quantizing and early_log.vq_start_step < 50
    assert after > 33 and after > early + 0.5, (after, early)
    assert 0.2 < log.vq_stats["used_fraction"] <= 1.0 and log.vq_stats["perplexity"] > 10, log.vq_stats


def test_fit_keeps_the_texels_exact_when_they_fit_the_index():
    """After training, k-means runs only when more texels were touched than ``quantize_above``; below it the
    baked codebook is the texels' own features (the index and codebook give back every texel exactly)."""
    data = synthetic_gbuffer()
    exact = NeuralTextureModel(32, 32, feature_dim=8, num_codes=64, use_vq=True)
    log = fit(exact, TrainingPixels(*data), steps=60, config=TrainConfig(batch_patches=8, patch=16), progress=False, num_threads=1)
    touched = int(exact.touched.sum())
    assert 64 < touched <= 1024 and log.exact_codes and log.vq_start_step is None and not exact.quantizing
    index, codebook = exact.baked_features()
    assert codebook.shape[0] <= touched and codebook.shape[0] > 64
    np.testing.assert_array_equal(codebook[index.reshape(-1)], exact.texture.flat.detach().numpy())

    capped = NeuralTextureModel(32, 32, feature_dim=8, num_codes=64, use_vq=True, quantize_above=touched - 1)
    log = fit(capped, TrainingPixels(*data), steps=60, config=TrainConfig(batch_patches=8, patch=16), progress=False, num_threads=1)
    assert capped.quantizing and not log.exact_codes and log.vq_start_step == 60
    assert capped.baked_features()[1].shape[0] <= 64


def test_the_plateau_rule_waits_for_half_the_run_and_a_flat_stretch():
    stop = PlateauStop(check_every=10, patience=3, min_gain_db=0.05, min_progress=0.5)
    rising = [20.0, 24.0, 26.0, 27.0, 27.5, 27.8, 28.0, 28.1]
    assert not any(stop.record(10 * (i + 1), p, 100) for i, p in enumerate(rising))    # still gaining 0.1+ dB
    flat = PlateauStop(check_every=10, patience=3, min_gain_db=0.05, min_progress=0.5)
    calls = [flat.record(10 * (i + 1), p, 100) for i, p in enumerate([20.0, 25.0, 26.0, 26.02, 26.01, 26.03, 26.0])]
    assert calls == [False, False, False, False, False, True, True]   # at 60: the last three's 26.03 < 26.0 + 0.05
    early = PlateauStop(check_every=10, patience=3, min_gain_db=0.05, min_progress=0.5)
    assert not any(early.record(10 * (i + 1), 26.0, 1000) for i in range(20))   # before half of 1000 steps


def test_fit_stops_on_a_plateau_of_held_back_pixels_it_never_trains_on():
    uv, cov, dirs, tgt = synthetic_gbuffer(n=2, res=32)
    before = cov.copy()
    torch.manual_seed(0)
    model = NeuralTextureModel(32, 32, feature_dim=8, num_codes=64)
    stop = PlateauStop(hold_back_every=16, check_every=50, patience=4, min_gain_db=0.05, min_progress=0.1)
    log = fit(model, TrainingPixels(uv, cov, dirs, tgt), steps=8000, config=TrainConfig(batch_patches=8, patch=8), progress=False,
              num_threads=1, stop=stop)
    assert log.stopped_by == "plateau" and 0.1 * 8000 <= log.steps < 8000, log.steps
    assert len(log.held_back) == log.steps // 50 and log.held_back[-1][1] > 30.0, log.held_back[-3:]
    assert np.array_equal(cov, before)                    # the caller's coverage is left as it was
    held = stop.held.numpy()
    assert held.size == int(np.ceil(before.sum() / 16)) and before.reshape(-1)[held].all()
    # the held-back pixels never reach the loss: the same fit on a coverage without them trains the same model
    kept = PlateauStop(hold_back_every=16, min_progress=2.0)            # scores, never stops
    small = TrainConfig(batch_patches=8, patch=8)
    torch.manual_seed(0)
    a = NeuralTextureModel(32, 32, feature_dim=8, num_codes=64, use_vq=False)
    fit(a, TrainingPixels(uv, cov, dirs, tgt), steps=200, config=small, progress=False, num_threads=1, stop=kept)
    masked = cov.copy()
    masked.reshape(-1)[kept.held.numpy()] = False
    torch.manual_seed(0)
    b = NeuralTextureModel(32, 32, feature_dim=8, num_codes=64, use_vq=False)
    fit(b, TrainingPixels(uv, masked, dirs, tgt), steps=200, config=small, progress=False, num_threads=1)
    assert all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))
    with pytest.raises(BadInputError, match="one process"):
        fit(model, TrainingPixels(uv, cov, dirs, tgt), steps=10, progress=False, stop=PlateauStop(), exchange=object())


def test_fit_time_budget_and_bad_input():
    data = synthetic_gbuffer(n=1, res=16)
    model = NeuralTextureModel(16, 16, feature_dim=4, num_codes=16, quantize_above=0)
    log = fit(model, TrainingPixels(*data), steps=100000, time_budget_s=0.5, config=TrainConfig(batch_patches=2), progress=False,
              num_threads=1)
    assert log.stopped_by == "time_budget" and log.steps < 100000 and model.quantizing
    uv, cov, dirs, tgt = data
    with pytest.raises(BadInputError):
        fit(model, TrainingPixels(uv, np.zeros_like(cov), dirs, tgt), steps=3, progress=False)
    with pytest.raises(BadInputError):
        fit(model, TrainingPixels(uv[..., :1], cov, dirs, tgt), steps=3, progress=False)


def test_playing_a_trained_model_quantizes_each_texel_once_and_matches_the_training_path():
    torch.manual_seed(0)
    model = NeuralTextureModel(16, 16, feature_dim=4, num_codes=32, hidden=8, use_viewdir=False)
    with torch.no_grad():
        model.texture.data.normal_()
    model.start_vq()
    uv = torch.rand(300, 2)
    model.train()
    trained, aux_t = model.features(uv)                 # the per-batch quantizer of training
    model.eval()
    with torch.no_grad():
        played, aux_p = model.features(uv)              # every texel's code, computed once and kept
        again, _ = model.features(uv)
    assert torch.equal(played, trained.detach()) and torch.equal(aux_p["indices"], aux_t["indices"])
    assert torch.equal(again, played) and model.vq._all_codes is not None
    with torch.no_grad():                               # a changed texel changes the kept codes' key
        model.texture.flat.data[:] = model.vq.codebook[0]
        moved, aux_m = model.features(uv)
    assert (aux_m["indices"] == 0).all() and not torch.equal(moved, played)
