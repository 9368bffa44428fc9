"""Training loss: gamma-weighted L1 over the model's sequence of flow predictions, valid pixels only."""

from __future__ import annotations

import torch

from ..errors import ProjregError


def sequence_loss(
    preds: list[torch.Tensor],
    flow_gt: torch.Tensor,
    valid: torch.Tensor,
    gamma: float = 0.9,
    max_flow: float | None = None,
) -> tuple[torch.Tensor, dict[str, float]]:
    """Weighted L1 loss of a prediction sequence, as RAFT / GMFlow, restricted to valid pixels.

    ``loss = sum_i gamma^(N-1-i) * L1_i``, where ``L1_i`` is the mean absolute error per flow
    component of prediction i over the valid pixels (``sum |du| + |dv|`` over valid pixels, divided by
    2 x their number), so later predictions weigh more. Invalid pixels contribute nothing, not even a
    NaN or inf in ``flow_gt`` or a prediction there. A batch without valid pixels gives a zero loss
    that is still connected to the graph (backward works, gradients are zero).

    Args:
        preds: N predictions, each ``[B, 2, H, W]``.
        flow_gt: ``[B, 2, H, W]`` ground truth.
        valid: ``[B, H, W]`` bool.
        gamma: decay, in (0, 1].
        max_flow: if given, pixels with ``|flow_gt| >= max_flow`` are also ignored.

    Returns:
        ``(loss, metrics)``; each metric is a detached 0-d tensor on the loss's device (``float()``
        it to read it: that waits for the device). ``metrics["loss"]`` is the loss, the others describe
        the last prediction over the counted pixels: ``epe`` (mean end-point error), ``px1``, ``px3``,
        ``px5`` (fraction with EPE > 1, 3, 5 px) and ``n_valid``; ``epe`` and the rates are NaN when
        no pixel counts.

    Convention: flow forward projected -> captured in pixels, channel 0 = u (x), 1 = v (y).
    """
    if not preds:
        raise ProjregError("sequence_loss needs at least one prediction")
    b, _, h, w = flow_gt.shape
    if flow_gt.shape[1] != 2 or valid.shape != (b, h, w):
        raise ProjregError(f"flow_gt {tuple(flow_gt.shape)} / valid {tuple(valid.shape)} are not [B,2,H,W] / [B,H,W]")
    if any(p.shape != flow_gt.shape for p in preds):
        raise ProjregError(f"every prediction must have shape {tuple(flow_gt.shape)}")
    if not 0.0 < gamma <= 1.0:
        raise ProjregError(f"gamma must be in (0, 1], got {gamma}")

    mask = valid.bool()[:, None]  # [B, 1, H, W]
    gt = torch.where(mask, flow_gt, torch.zeros((), dtype=flow_gt.dtype, device=flow_gt.device))
    if max_flow is not None:
        mask = mask & (gt.norm(dim=1, keepdim=True) < max_flow)
    n_valid = mask.sum()
    denom = (2 * n_valid).clamp(min=1).to(gt.dtype)

    n = len(preds)
    loss = preds[0].new_zeros(())
    for i, pred in enumerate(preds):
        # where(), not a product with the mask, so a NaN outside the mask cannot leak into loss or grad
        err = torch.where(mask, pred - gt, torch.zeros((), dtype=pred.dtype, device=pred.device)).abs()
        loss = loss + gamma ** (n - 1 - i) * err.sum() / denom

    with torch.no_grad():  # no host synchronisation: the trainer reads these once per log interval
        epe = (preds[-1] - gt).norm(dim=1, keepdim=True)  # [B, 1, H, W]
        counted = mask.to(epe.dtype)
        nan = torch.full((), float("nan"), dtype=epe.dtype, device=epe.device)

        def share(values: torch.Tensor) -> torch.Tensor:
            return torch.where(n_valid > 0, (values * counted).sum() / n_valid.clamp(min=1), nan)

        metrics = {
            "loss": loss.detach(),
            "epe": share(torch.where(mask, epe, torch.zeros((), dtype=epe.dtype, device=epe.device))),
            "px1": share((epe > 1).to(epe.dtype)),
            "px3": share((epe > 3).to(epe.dtype)),
            "px5": share((epe > 5).to(epe.dtype)),
            "n_valid": n_valid.to(epe.dtype),
        }
    return loss, metrics
