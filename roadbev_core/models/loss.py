"""Elevation by classification on bins: targets, masked cross-entropy (paper eq. 3), soft-argmin.

Targets are built in torch with the conventions of :mod:`roadbev_core.labels` (``one_hot``:
the bin holding the elevation; ``two_hot``: split between the two nearest bin centres so that its
expectation is the elevation itself), so training needs no per-cell numpy work.
"""

from __future__ import annotations

import torch

from roadbev_core.config import GridSpec

__all__ = ["class_targets", "masked_cross_entropy", "soft_argmin"]


def class_targets(elevation: torch.Tensor, grid: GridSpec, label: str = "two_hot") -> tuple[torch.Tensor, torch.Tensor]:
    """Soft class targets and the label mask of elevation maps.

    Args:
        elevation: [B, R, C] metres, NaN where there is no label.
        grid: gives the bins (``z_min``, ``class_resolution``, ``n_classes``).
        label: ``one_hot`` or ``two_hot``.

    Returns:
        target [B, Nc, R, C] float32 (zeros where unlabelled), mask [B, R, C] bool.
    """
    mask = torch.isfinite(elevation)
    e = torch.nan_to_num(elevation.to(torch.float64), nan=0.0)
    n = grid.n_classes
    target = torch.zeros((e.shape[0], n, *e.shape[1:]), dtype=torch.float32, device=e.device)
    if label == "one_hot":
        idx = torch.floor((e - grid.z_min) / grid.class_resolution).clamp(0, n - 1).long()
        target.scatter_(1, idx[:, None], 1.0)
    elif label == "two_hot":
        first = grid.z_min + 0.5 * grid.class_resolution
        pos = ((e - first) / grid.class_resolution).clamp(0, n - 1)  # fractional bin index
        lo = pos.floor().clamp(0, n - 2).long()
        w_hi = (pos - lo).to(torch.float32)
        target.scatter_(1, lo[:, None], (1.0 - w_hi)[:, None])
        target.scatter_add_(1, (lo + 1)[:, None], w_hi[:, None])
    else:
        raise ValueError(f"label must be 'one_hot' or 'two_hot', got {label!r}")
    return target * mask[:, None], mask


def masked_cross_entropy(
    logits: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, normaliser: float | None = None
) -> torch.Tensor:
    """Cross-entropy over labelled cells (paper eq. 3), divided by the labelled-cell count.

    Args:
        logits: [B, Nc, R, C].
        target: [B, Nc, R, C] class distribution per cell.
        mask: [B, R, C] bool.
        normaliser: divide by this instead of this batch's labelled cells (distributed training
            divides by the global count so that ranks add up to the single-process loss).
    """
    log_p = torch.log_softmax(logits.float(), dim=1)
    per_cell = -(target * log_p).sum(dim=1)  # [B, R, C]
    total = (per_cell * mask).sum()
    count = float(mask.sum()) if normaliser is None else normaliser
    return total / max(count, 1.0)


def soft_argmin(logits: torch.Tensor, centres: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Expected elevation and its standard deviation under the softmax bin distribution.

    Args:
        logits: [B, Nc, R, C].
        centres: [Nc] bin centres (metres).

    Returns:
        elevation [B, R, C], uncertainty [B, R, C] (1-sigma, metres).
    """
    p = torch.softmax(logits.float(), dim=1)
    e = centres.to(p)[None, :, None, None]
    mean = (p * e).sum(dim=1)
    var = (p * (e - mean[:, None]) ** 2).sum(dim=1)
    return mean, var.clamp_min(0).sqrt()
