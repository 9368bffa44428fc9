"""``projreg export --onnx``: the network (without the geometric refinement) as an ONNX graph.

The graph takes ``projected`` and ``captured``, float32 ``[N, 3, H, W]`` RGB in [0, 255], and gives
``flow``, float32 ``[N, 2, H, W]``, forward (projected -> captured) in pixels: the last prediction of
:class:`~projreg.model.net.SSJMFlow`. Batch, height and width are dynamic; the graph pads to its
multiple of ``8 * attn_splits`` itself (:func:`~projreg.model.net.pad_replicate`) and crops back, as
the PyTorch model does. Exported with ``torch.export`` (the dynamo exporter): the split-window
attention's shifts are slices of symbolic sizes (:func:`~projreg.model.transformer.roll2d`), and
``grid_sample`` (the 1/4 refinement's warp) needs opset 16 or later.

The file is self-contained (weights inside, no ``.onnx.data`` beside it) and records its provenance
in the model's metadata: ``projreg_model_config`` (JSON), ``projreg_checkpoint`` and its SHA-256,
``projreg_version``.

Convention: as :class:`~projreg.model.net.SSJMFlow`; ``flow[:, 0]`` is u (right), ``flow[:, 1]`` v (down).
"""

from __future__ import annotations

import contextlib
import json
import logging
import warnings
from pathlib import Path

import torch
from torch import nn

from projsynth.errors import ProjsynthError
from projsynth.utils.files import file_sha256, write_atomic_all

from ..errors import ProjregError
from ..model.net import SSJMFlow
from ..versions import __version__

INPUTS = ("projected", "captured")
OUTPUT = "flow"
MIN_OPSET = 16  # grid_sample
DEFAULT_OPSET = 18


def max_opset() -> int:
    """The newest opset the installed torch's exporter writes (23 for torch 2.13)."""
    try:
        from torch.onnx._constants import ONNX_MAX_OPSET
    except ImportError:  # a torch that moved it: the default is known to work
        return DEFAULT_OPSET
    return int(ONNX_MAX_OPSET)


def check_opset(opset: int) -> None:
    """Refuse an opset the network cannot be written in (below ``MIN_OPSET``) or the exporter does not know."""
    if not MIN_OPSET <= opset <= max_opset():
        raise ProjregError(
            f"--opset {opset}: the exporter writes opsets {MIN_OPSET}..{max_opset()} "
            f"(the network's grid_sample needs >= {MIN_OPSET}); the default is {DEFAULT_OPSET}"
        )


class FlowGraph(nn.Module):
    """What the ONNX graph computes: the network's final flow only (``SSJMFlow(...)[-1]``)."""

    def __init__(self, model: SSJMFlow) -> None:
        super().__init__()
        self.model = model

    def forward(self, projected: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
        return self.model(projected, captured)[-1]  # [N, 2, H, W]


@contextlib.contextmanager
def _quiet(logger: str):
    """The exporter logs its progress and missing optional packages (torchvision) on stderr; errors only."""
    log = logging.getLogger(logger)
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def require_onnx(option: str = "--onnx"):
    """The ``onnx`` module, or a ProjregError saying how to install the optional extra."""
    try:
        import onnx
    except ImportError:
        raise ProjregError(f"{option} needs the onnx package: pip install 'projsynth[onnx]'") from None
    return onnx


def export_onnx(model: SSJMFlow, out: Path, *, opset: int = DEFAULT_OPSET, metadata: dict | None = None) -> Path:
    """Write ``model``'s network (eval mode, float32, CPU) as a self-contained ONNX file, atomically.

    Args:
        model: the network; it is exported as :class:`FlowGraph` and checked with ``onnx.checker``.
        out: the ``.onnx`` file to write (parents created).
        opset: ONNX opset, ``MIN_OPSET`` to :func:`max_opset`.
        metadata: extra ``metadata_props`` (string values), e.g. the checkpoint it came from.

    Returns:
        ``out``.

    Raises:
        ProjregError: opset too low, ``onnx`` (or ``onnxscript``) missing, the export or the checker failed.
    """
    check_opset(opset)
    onnx = require_onnx()
    out = Path(out)
    if out.suffix.lower() != ".onnx":
        raise ProjregError(f"--onnx {out}: give a name ending in .onnx")
    graph = FlowGraph(model.float().cpu().eval())
    # an example of batch 2, a size that is no multiple of the padding and windows wider than 1: with
    # sizes of 1 (batch, a half window) or an unpadded example the tracer would specialise them
    example = tuple(torch.full((2, 3, 40, 52), 128.0) for _ in INPUTS)
    batch, height, width = torch.export.Dim("batch"), torch.export.Dim("height"), torch.export.Dim("width")
    dims = {name: {0: batch, 2: height, 3: width} for name in INPUTS}
    try:
        with warnings.catch_warnings(), torch.no_grad(), _quiet("torch.onnx"):  # no_grad: a faster trace
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                graph,
                example,
                input_names=list(INPUTS),
                output_names=[OUTPUT],
                dynamic_shapes=dims,
                opset_version=opset,
                dynamo=True,
                verbose=False,
            )
    except ImportError as e:
        raise ProjregError(f"--onnx needs {e.name or 'onnxscript'}: pip install 'projsynth[onnx]'") from e
    except Exception as e:  # the exporter's own errors carry pages of context; keep the first line
        raise ProjregError(f"--onnx {out}: export failed: {str(e).strip().splitlines()[0]:.300}") from e
    proto = program.model_proto
    for k, name in ((0, "batch"), (2, "height"), (3, "width")):  # the exporter names them by formula
        proto.graph.output[0].type.tensor_type.shape.dim[k].dim_param = name
    props = {
        "projreg_model_config": json.dumps(model.config, sort_keys=True),
        "projreg_version": __version__,
        **(metadata or {}),
    }
    for key, value in props.items():
        proto.metadata_props.add(key=key, value=str(value))
    _drop_stack_traces(proto)
    try:
        onnx.checker.check_model(proto, full_check=True)
    except Exception as e:
        raise ProjregError(f"--onnx {out}: the exported graph fails onnx.checker: {e}") from e
    try:
        write_atomic_all([(out, proto.SerializeToString())], make_parents=True)
    except ProjsynthError as e:
        raise ProjregError(f"--onnx {e}") from e
    return out


def _drop_stack_traces(proto) -> None:
    """Remove the exporter's per-node Python stack traces: they name the tracer's generated code by a
    counter (``<eval_with_key>.39``), so two exports of one checkpoint would differ in bytes."""
    for node in proto.graph.node:
        kept = [p for p in node.metadata_props if not p.key.endswith("stack_trace")]
        if len(kept) != len(node.metadata_props):
            del node.metadata_props[:]
            node.metadata_props.extend(kept)


def export_checkpoint_onnx(checkpoint: Path | str | None, out: Path, *, opset: int = DEFAULT_OPSET) -> Path:
    """``projreg export --onnx``: a checkpoint's network as an ONNX graph (:func:`export_onnx`).

    Args:
        checkpoint: a ``projreg train``/``export`` checkpoint; None or ``reference``: the shipped model.
        out: the ``.onnx`` file; it must not be the checkpoint itself.
        opset: ONNX opset (:func:`check_opset`).

    Returns:
        ``out``; its metadata names the checkpoint and its SHA-256.
    """
    from ..model.checkpoint import load_model, resolve_checkpoint

    check_opset(opset)
    if Path(out).suffix.lower() != ".onnx":
        raise ProjregError(f"--onnx {out}: give a name ending in .onnx")
    require_onnx()
    path = resolve_checkpoint(checkpoint)
    if Path(out).resolve() == path.resolve():
        raise ProjregError(f"--onnx {out}: is the checkpoint being exported; write the graph to another file")
    model = load_model(path, torch.device("cpu"))
    meta = {"projreg_checkpoint": path.name, "projreg_checkpoint_sha256": file_sha256(path)}
    return export_onnx(model, Path(out), opset=opset, metadata=meta)
