"""Vector quantisation on extreme features: offset by 1e4, all identical, more codes than texels; nearest code
against a float64 brute force."""

from __future__ import annotations

import pytest
import torch

from neuras_distill.neural.vq import VectorQuantizer

S = pytest.mark.stability


def _brute(z, codebook):
    return ((z.double()[:, None, :] - codebook.double()[None]) ** 2).sum(-1).argmin(1)


@S(case="VQ nearest code, features offset by 1e4", family="vq",
   reference="float64 brute-force argmin on the same float32 values",
   tolerance="100% agreement (checked: the uncentred expanded form |x|^2 + |e|^2 - 2x.e fails at 1e3 and 1e4)")
@pytest.mark.parametrize("offset", [0.0, 1e3, 1e4])
def test_offset_features(offset):
    g = torch.Generator().manual_seed(0)
    q = VectorQuantizer(64, 8)
    codes = offset + torch.randn(64, 8, generator=g) * 0.01
    q.codebook.data.copy_(codes)
    z = codes[torch.randint(0, 64, (4096,), generator=g)] + torch.randn(4096, 8, generator=g) * 1e-3
    assert torch.equal(q.quantize_all(z), _brute(z, q.codebook.data))


@S(case="VQ all features identical", family="vq",
   reference="k-means init: finite codebook, every feature maps to a code equal to it",
   tolerance="absolute 1e-5 on the quantised value")
def test_identical_features():
    q = VectorQuantizer(16, 4)
    z = torch.full((500, 4), 3.25)
    q.init_from(z, generator=torch.Generator().manual_seed(0))
    assert torch.isfinite(q.codebook).all()
    zq, idx, loss = q(z)
    assert torch.allclose(zq, z, atol=1e-5) and float(loss.detach()) <= 1e-9 and idx.unique().numel() == 1


@S(case="VQ more codes than texels", family="vq",
   reference="k-means init with 1024 codes for 10 features: each feature quantises to itself",
   tolerance="absolute 1e-3 (the init jitter); codebook finite; no error")
def test_more_codes_than_texels():
    g = torch.Generator().manual_seed(0)
    q = VectorQuantizer(1024, 8)
    z = torch.randn(10, 8, generator=g)
    q.init_from(z, generator=g)
    assert torch.isfinite(q.codebook).all()
    zq, idx, _ = q(z)
    assert torch.allclose(zq, z, atol=1e-3)
    assert torch.equal(idx, _brute(z, q.codebook.data))


@S(case="VQ more codes than texels: every texel its own code", family="vq",
   reference="k-means init with 1024 codes for 1000 distinct texels: 1000 distinct codes, each texel quantises to "
             "itself (seeding with replacement: 758 distinct codes for the 1000 texels with this seed)",
   tolerance="exact: 1000 distinct indices, the quantised value equal to the texel")
def test_every_texel_own_code():
    g = torch.Generator().manual_seed(0)
    q = VectorQuantizer(1024, 8)
    z = torch.randn(1000, 8, generator=g)
    q.init_from(z, generator=g)
    zq, idx, _ = q(z)
    assert idx.unique().numel() == 1000
    assert torch.equal(zq, z)
