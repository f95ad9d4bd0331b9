"""Image losses and metrics; LPIPS through a stand-in weight file in the documented format."""

import pytest
import torch

from signsplat.avatar.losses import (
    LPIPS,
    blur_matrix,
    dssim,
    image_loss,
    load_lpips,
    psnr,
    ssim,
    ssim_map,
)
from signsplat.errors import InputError


def test_psnr_known_values_and_mask():
    a = torch.zeros(1, 3, 8, 8)
    b = torch.full((1, 3, 8, 8), 0.1)
    torch.testing.assert_close(psnr(a, b), torch.tensor([20.0]))
    mask = torch.zeros(1, 1, 8, 8)
    mask[..., :4] = 1
    b2 = b.clone()
    b2[..., 4:] = 0.5  # errors outside the mask do not count
    torch.testing.assert_close(psnr(a, b2, mask), torch.tensor([20.0]))
    assert float(psnr(a, b2)) < 20.0


def test_ssim_and_dssim():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 16, 16, generator=g)
    assert float(dssim(x, x)) == pytest.approx(0.0, abs=1e-5)
    torch.testing.assert_close(ssim(x, x), torch.ones(2))
    y = (x + 0.2 * torch.randn(2, 3, 16, 16, generator=g)).clamp(0, 1)
    assert float(dssim(x, y)) > 0.05
    terms = image_loss(x, y, 0.8, 0.2)
    assert set(terms) == {"l1", "dssim"}  # no LPIPS without weights


def _standin(path, drop=None):
    """Random weights in the documented merged-file format (torchvision + lpips names)."""
    torch.manual_seed(0)
    net = LPIPS()
    state = {}
    for key, v in net.state_dict().items():
        if key.startswith("features."):
            state[key] = torch.randn_like(v) * 0.1
        elif key.startswith("lins."):
            n = key.split(".")[1]
            state[f"lin{n}.model.1.weight"] = torch.rand_like(v)
    if drop:
        state.pop(drop)
    torch.save(state, path)


def test_lpips_from_a_local_file(tmp_path):
    assert load_lpips(None) is None
    _standin(tmp_path / "lpips.pth")
    net = load_lpips(tmp_path / "lpips.pth")
    g = torch.Generator().manual_seed(1)
    x = torch.rand(1, 3, 64, 64, generator=g)
    y = torch.rand(1, 3, 64, 64, generator=g)
    assert float(net(x, x)) == pytest.approx(0.0, abs=1e-6)
    assert float(net(x, y)) > float(net(x, (x + 0.02).clamp(0, 1))) > 0
    terms = image_loss(x, y, 0.8, 0.2, lpips=net, w_lpips=0.1)
    assert "lpips" in terms and float(terms["lpips"]) > 0


def test_lpips_bad_files_name_the_problem(tmp_path):
    with pytest.raises(InputError, match="not found"):
        load_lpips(tmp_path / "missing.pth")
    _standin(tmp_path / "bad.pth", drop="lin2.model.1.weight")
    with pytest.raises(InputError, match="lin2.model.1.weight"):
        load_lpips(tmp_path / "bad.pth")


@pytest.mark.parametrize("shape,window", [((2, 3, 37, 23), 11), ((1, 3, 16, 64), 11),
                                          ((1, 1, 9, 12), 7), ((1, 3, 6, 20), 11)])
def test_ssim_map_is_kornias_forward_and_backward(shape, window):
    import kornia

    g = torch.Generator().manual_seed(5)
    x = torch.rand(*shape, generator=g, dtype=torch.float64)
    y = (x + 0.3 * torch.randn(*shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    a, b = x.clone().requires_grad_(), x.clone().requires_grad_()
    if min(shape[-2:]) > window // 2:  # kornia's reflect padding needs that
        ref = kornia.metrics.ssim(b, y, window)
        ours = ssim_map(a, y, window)
        torch.testing.assert_close(ours, ref)
        w = torch.rand(*shape, generator=g, dtype=torch.float64)
        (ours * w).sum().backward()
        (ref * w).sum().backward()
        torch.testing.assert_close(a.grad, b.grad)
    else:  # shorter than the window's half: still a blur whose rows sum to one
        m = blur_matrix(shape[-2], window, torch.float64)
        torch.testing.assert_close(m.sum(1), torch.ones(shape[-2], dtype=torch.float64))
        assert float(ssim(x, x)) == pytest.approx(1.0)
