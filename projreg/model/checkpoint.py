"""Checkpoints in one place: reading them safely, the model they describe, writing them atomically, the
deployable export and the shipped reference model.

A checkpoint is a ``torch.save`` of tensors and plain containers (``torch.load(..., weights_only=True)``):
``model`` (state dict) and ``model_config`` always; a training checkpoint (``projreg train``'s
``last.pt``/``best.pt``) also ``optimizer``, ``scheduler``, ``rng``, ``step``, ``best_epe``,
``train_config`` and ``version``; an export (``projreg export``) keeps the model, its config and the
provenance (``step``, ``best_epe``, ``train_config``, ``version``).
"""

from __future__ import annotations

import importlib.resources
import io
from pathlib import Path

import torch

from projsynth.errors import ProjsynthError
from projsynth.utils.files import write_atomic

from ..errors import ProjregError
from .net import SSJMFlow, checked_config


def atomic_save(obj: dict, path: Path, then: str = "then --resume") -> None:
    """``torch.save`` of ``obj`` to ``path``, whole or not at all (:func:`projsynth.utils.files.write_atomic`)."""
    buffer = io.BytesIO()
    torch.save(obj, buffer)
    try:
        write_atomic(Path(path), buffer.getbuffer())
    except ProjsynthError as e:
        reason = getattr(e.__cause__, "strerror", None) or e.__cause__ or e
        raise ProjregError(f"{path}: cannot write checkpoint ({reason}); free space or fix permissions, {then}") from e


def load_checkpoint(path: Path) -> dict:
    """Load a checkpoint safely (``weights_only=True``); errors name the file."""
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise ProjregError(f"{path}: no such checkpoint") from None
    except IsADirectoryError:
        raise ProjregError(f"{path}: is a folder; pass a checkpoint file (RUN/checkpoints/last.pt)") from None
    except Exception as e:  # torch raises many types, with multi-line messages that suggest weights_only=False
        raise ProjregError(
            f"{path}: not a readable checkpoint ({type(e).__name__}); pass a checkpoint written by `projreg train`"
        ) from e


def export_checkpoint(src: Path, dst: Path) -> dict:
    """Write the deployable part of a training checkpoint: weights, architecture and provenance.

    Drops the optimizer, scheduler and RNG states (two thirds of a ``last.pt``); keeps ``model``,
    ``model_config``, ``step``, ``best_epe``, ``train_config`` and ``version``, so ``bench`` and
    ``predict`` load the result like any checkpoint and it still says how it was trained.

    Returns:
        The exported dictionary.
    """
    if Path(dst).resolve() == Path(src).resolve():
        raise ProjregError(f"--out {dst}: is the checkpoint being exported; write the export to another file")
    ckpt = require_model(load_checkpoint(Path(src)), src)
    try:
        model_from_checkpoint(ckpt)  # what bench and predict will do with the export
    except (ValueError, ProjregError) as e:
        raise ProjregError(f"{src}: weights do not match the checkpoint's model_config ({e}); not exported") from e
    slim = {k: ckpt[k] for k in ("model", "model_config", "step", "best_epe", "train_config", "version") if k in ckpt}
    slim["model"] = {k: v.detach().clone().contiguous() for k, v in slim["model"].items()}  # no shared storage
    try:
        Path(dst).parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ProjregError(f"--out {dst}: cannot create its folder ({e.strerror or e})") from e
    atomic_save(slim, Path(dst), then="then export again")
    return slim


def require_model(ckpt, path: Path) -> dict:
    """``ckpt`` if it holds a model (``model`` and ``model_config``), else a ProjregError naming ``path``."""
    if not isinstance(ckpt, dict) or "model" not in ckpt or "model_config" not in ckpt:
        raise ProjregError(f"{path}: not a projreg checkpoint (no model / model_config); pass one from `projreg train`")
    return ckpt


def model_from_checkpoint(ckpt: dict) -> SSJMFlow:
    """The network a checkpoint describes, its ``model_config`` bounded (``checked_config``) before the
    model is built; an out-of-bounds config raises ProjregError, a mismatch between weights and config
    a one-line ValueError."""
    try:
        model = SSJMFlow(**checked_config(ckpt["model_config"]))
        model.load_state_dict(ckpt["model"])
    except (TypeError, RuntimeError) as e:  # load_state_dict lists every mismatched tensor on its own line
        lines = [line.strip() for line in str(e).splitlines() if line.strip()]
        raise ValueError(" ".join(lines[1:3] if len(lines) > 1 else lines)) from e
    bad = [k for k, v in model.state_dict().items() if v.is_floating_point() and not torch.isfinite(v).all()]
    if bad:
        raise ValueError(f"non-finite weights in {bad[0]}" + (f" and {len(bad) - 1} more" if len(bad) > 1 else ""))
    return model


NO_REFERENCE = "no shipped reference model yet; pass --model CKPT (train one with `projreg train`)"


def reference_checkpoint() -> Path | None:
    """The shipped reference model ``projreg/weights/reference.pt``, or None while none ships."""
    ref = importlib.resources.files("projreg").joinpath("weights", "reference.pt")
    return Path(str(ref)) if ref.is_file() else None


def reference_graph() -> Path | None:
    """The shipped reference model's ONNX graph ``projreg/weights/reference.onnx`` (``make reference-onnx``:
    ``projreg export --onnx`` of the shipped checkpoint), or None while none ships."""
    ref = importlib.resources.files("projreg").joinpath("weights", "reference.onnx")
    return Path(str(ref)) if ref.is_file() else None


def resolve_checkpoint(spec: Path | str | None) -> Path:
    """``spec`` as a checkpoint path; None or the name ``reference`` (when no such file exists) is the
    shipped reference model. Raises ProjregError when that is asked for and none ships."""
    if spec is not None and not (str(spec) == "reference" and not Path(spec).exists()):
        return Path(spec)
    ref = reference_checkpoint()
    if ref is None:
        raise ProjregError(NO_REFERENCE)
    return ref


def load_model(path: Path, device: torch.device) -> SSJMFlow:
    """A checkpoint written by ``projreg train``, on ``device``, in eval mode; errors name the file."""
    ckpt = require_model(load_checkpoint(Path(path)), path)
    try:
        model = model_from_checkpoint(ckpt)
    except (ValueError, ProjregError) as e:
        raise ProjregError(
            f"{path}: weights do not match the checkpoint's model_config ({e}); "
            "pass a checkpoint as `projreg train` or `projreg export` wrote it"
        ) from e
    return model.to(device).eval()
