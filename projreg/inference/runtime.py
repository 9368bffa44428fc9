"""Where and how the network runs: device, precision, backend and batches (``predict`` and ``bench``).

A *network* here is a callable ``net(projected, captured) -> flow`` on batches of numpy arrays:
uint8 RGB ``[N, H, W, 3]`` each, float32 ``[N, H, W, 2]`` out, forward (projected -> captured) in
pixels: the last prediction of :class:`~projreg.model.net.SSJMFlow`, without the geometric refinement.
Two backends give one:

* ``torch``: a checkpoint on ``cpu``, ``cuda`` or ``cuda:N``, in ``fp32``, ``bf16`` or ``fp16``
  (:meth:`~projreg.model.net.SSJMFlow.cast_features`: the backbone, SSJM and transformer weights are
  cast; matching, propagation, the 1/4 refinement and upsampling stay float32);
* ``onnxruntime``: a graph written by ``projreg export --onnx`` (float32), on the CPU or, where
  onnxruntime has it, CUDA;
* ``auto`` (the default): onnxruntime for a float32 network on the CPU where it is installed and a graph
  of the model is at hand (a ``.onnx`` model, or the shipped reference model's graph
  ``projreg/weights/reference.onnx``, exported from the shipped checkpoint); torch otherwise. The
  same network either way, to float rounding (about 1e-3 px), and on the CPU onnxruntime's fused
  kernels wake its threads far less often than torch's operators: on the 2-core VM the network at
  256 px took 90-105 ms against torch's 155-170 with ``OMP_WAIT_POLICY=PASSIVE`` (what the tools set for
  a shared machine), and stays ahead beside a competing job (docs/design.md, "Threads on a shared machine").

:func:`flows_resized` runs a list of pairs through a network, shrinking those longer than ``max_side``
and batching pairs whose network inputs share a size.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch

from projsynth.utils.files import file_sha256

from ..errors import ProjregError
from ..geometry.frames import resize_flow, shrink
from ..model.net import SSJMFlow
from .onnx_export import INPUTS, OUTPUT

Network = Callable[[np.ndarray, np.ndarray], np.ndarray]

PRECISIONS = {"fp32": torch.float32, "bf16": torch.bfloat16, "fp16": torch.float16}
BACKENDS = ("auto", "torch", "onnxruntime")
DEFAULT_BACKEND = "auto"
EXTRA = "pip install 'projsynth[onnx]'"


def default_device() -> torch.device:
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def parse_device(text: str | torch.device | None) -> torch.device:
    """``cpu``, ``cuda`` or ``cuda:N`` as a device that exists here; None: CUDA when available, else CPU.

    Raises:
        ProjregError: naming ``--device`` when the text is no such device or CUDA is not available.
    """
    if text is None:
        return default_device()
    text = str(text)
    try:
        device = torch.device(text.strip().lower())
    except RuntimeError:
        device = None
    if device is None or device.type not in ("cpu", "cuda") or (device.type == "cpu" and device.index):
        raise ProjregError(f"--device {text!r}: expected cpu, cuda or cuda:N")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            build = "a CPU-only build" if torch.version.cuda is None else "no CUDA device visible"
            raise ProjregError(
                f"--device {text}: CUDA is not available here (torch {torch.__version__}, {build}); use --device cpu"
            )
        if (device.index or 0) >= torch.cuda.device_count():
            raise ProjregError(f"--device {text}: only {torch.cuda.device_count()} CUDA device(s) here")
    return device


def parse_precision(text: str, device: torch.device) -> torch.dtype:
    """``fp32``, ``bf16`` or ``fp16`` as a dtype the device runs; fp16 is refused on the CPU.

    Half precision on the CPU is an emulation there: the reference network took 7x longer in fp16
    than in fp32 on the 2-core CI VM (docs/history/2026-11-log.md), so it is an error rather than a slow surprise.
    """
    if text not in PRECISIONS:
        raise ProjregError(f"--precision {text!r}: expected one of {', '.join(PRECISIONS)}")
    if text == "fp16" and device.type == "cpu":
        raise ProjregError(
            "--precision fp16: float16 runs on CUDA only (on the CPU it is emulated, 7x slower "
            "than fp32); use --precision bf16 or fp32, or --device cuda"
        )
    if text == "bf16" and device.type == "cuda" and not torch.cuda.is_bf16_supported():
        raise ProjregError(f"--precision bf16: {torch.cuda.get_device_name(device)} has no bfloat16; use fp16")
    return PRECISIONS[text]


class TorchNetwork:
    """A :class:`~projreg.model.net.SSJMFlow` in eval mode on ``device``, feature stages in ``dtype``."""

    def __init__(
        self, model: SSJMFlow, device: torch.device, dtype: torch.dtype = torch.float32, source: str = "the network"
    ) -> None:
        self.model = model.to(device).eval().cast_features(dtype)
        self.device = device
        self.source = source  # how errors name it: the checkpoint

    @torch.no_grad()
    def __call__(self, projected: np.ndarray, captured: np.ndarray) -> np.ndarray:
        t0, t1 = (
            torch.from_numpy(np.ascontiguousarray(x)).to(self.device).permute(0, 3, 1, 2).float()
            for x in (projected, captured)
        )  # [N, 3, H, W] each
        return self.model(t0, t1)[-1].permute(0, 2, 3, 1).float().cpu().numpy()  # [N, H, W, 2]


class OnnxNetwork:
    """A graph written by ``projreg export --onnx``, in an onnxruntime session.

    ``threads``: onnxruntime's intra-op threads (default: as many as torch uses). They sleep when out of
    work instead of spinning (``session.intra_op.allow_spinning`` 0): idle as fast, and beside another job
    they leave it the cores (docs/design.md, "Threads on a shared machine").
    """

    def __init__(self, path: Path, device: torch.device, threads: int | None = None) -> None:
        try:
            import onnxruntime as ort
        except ImportError:
            raise ProjregError(f"--backend onnxruntime needs the onnxruntime package: {EXTRA}") from None
        self.source = f"--model {path}"
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads or torch.get_num_threads()
        options.log_severity_level = 3  # warnings about unused initialisers are not the user's concern
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        providers: list = ["CPUExecutionProvider"]
        if device.type == "cuda":
            if "CUDAExecutionProvider" not in ort.get_available_providers():
                raise ProjregError(
                    "--device cuda with --backend onnxruntime needs onnxruntime-gpu (this onnxruntime "
                    f"has {', '.join(ort.get_available_providers())})"
                )
            providers.insert(0, ("CUDAExecutionProvider", {"device_id": device.index or 0}))
        try:
            self.session = ort.InferenceSession(str(path), options, providers=providers)
        except Exception as e:
            raise ProjregError(
                f"--model {path}: onnxruntime cannot load it ({str(e).strip().splitlines()[0]:.200}); "
                "pass a graph written by `projreg export --onnx`"
            ) from e
        names = [i.name for i in self.session.get_inputs()], [o.name for o in self.session.get_outputs()]
        if names != (list(INPUTS), [OUTPUT]):
            raise ProjregError(
                f"--model {path}: inputs {names[0]} and outputs {names[1]}, expected {list(INPUTS)} "
                f"and [{OUTPUT!r}]; pass a graph written by `projreg export --onnx`"
            )
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)  # its provenance (onnx_export)

    def __call__(self, projected: np.ndarray, captured: np.ndarray) -> np.ndarray:
        feed = {
            name: np.ascontiguousarray(x.transpose(0, 3, 1, 2), np.float32)
            for name, x in zip(INPUTS, (projected, captured), strict=True)
        }  # [N, 3, H, W] each
        return self.session.run([OUTPUT], feed)[0].transpose(0, 2, 3, 1)  # [N, H, W, 2]


def open_network(
    model: Path | str | None,
    *,
    backend: str = DEFAULT_BACKEND,
    device: str | torch.device | None = None,
    precision: str = "fp32",
) -> Network:
    """The network of ``model`` on a backend (module docstring), checked before any pair is read.

    Args:
        model: a checkpoint (``torch``; None or ``reference``: the shipped reference model) or a
            ``.onnx`` file written by ``projreg export --onnx`` (``onnxruntime``).
        backend: ``auto`` (the default), ``torch`` or ``onnxruntime`` (module docstring).
        device: ``cpu``, ``cuda``, ``cuda:N``; None: CUDA when available, else the CPU.
        precision: ``fp32``, ``bf16`` or ``fp16`` (``onnxruntime``: fp32 only).

    Raises:
        ProjregError: one line naming the option that cannot be honoured here.
    """
    from ..model.checkpoint import load_model, resolve_checkpoint

    if backend not in BACKENDS:
        raise ProjregError(f"--backend {backend!r}: expected one of {', '.join(BACKENDS)}")
    dev = parse_device(device)
    dtype = parse_precision(precision, dev)
    is_onnx = model is not None and Path(model).suffix.lower() == ".onnx"
    if backend == "auto":
        if not is_onnx and (net := _reference_graph(model, dev, precision)) is not None:
            return net
        backend = "onnxruntime" if is_onnx else "torch"
    if backend == "torch":
        if is_onnx:
            raise ProjregError(f"--model {model}: an ONNX graph; run it with --backend onnxruntime")
        path = resolve_checkpoint(model)
        return TorchNetwork(load_model(path, dev), dev, dtype, source=f"--model {path}")
    if not is_onnx:
        raise ProjregError(
            "--backend onnxruntime runs an exported graph: pass --model FILE.onnx (write it with "
            "`projreg export --onnx FILE.onnx`)"
        )
    if precision != "fp32":
        raise ProjregError(
            f"--precision {precision}: the onnxruntime backend runs the exported float32 graph; "
            "use --backend torch for bf16/fp16"
        )
    if not Path(model).is_file():
        raise ProjregError(f"--model {model}: no such file")
    return OnnxNetwork(Path(model), dev)


def _reference_graph(model: Path | str | None, device: torch.device, precision: str) -> OnnxNetwork | None:
    """The shipped reference graph in onnxruntime, where ``auto`` runs it (module docstring): ``model``
    is the shipped reference model (or a copy of its file), the network runs in float32 on the CPU,
    onnxruntime is installed, and the graph records the shipped checkpoint's SHA-256 (else None: torch
    runs the checkpoint)."""
    from ..model.checkpoint import reference_checkpoint, reference_graph, resolve_checkpoint

    if device.type != "cpu" or precision != "fp32" or importlib.util.find_spec("onnxruntime") is None:
        return None
    ref, graph, path = reference_checkpoint(), reference_graph(), resolve_checkpoint(model)
    if ref is None or graph is None or not path.is_file():
        return None
    sha = file_sha256(ref)
    if path.resolve() != ref.resolve() and file_sha256(path) != sha:
        return None
    net = OnnxNetwork(graph, device)
    return net if net.metadata.get("projreg_checkpoint_sha256") == sha else None


def finer_flow(
    net: Network, projected: np.ndarray, captured: np.ndarray, side: int | None
) -> Callable[[], np.ndarray] | None:
    """The network's flow for one pair with the captured image at the projected one's size, shrunk to
    ``side`` at most, as a call the refinement makes only when its first stage escalates (None: no ``side``)."""
    return None if side is None else (lambda: flows_resized(net, [(projected, captured)], side)[0])


def checked_flow(net: Network, out: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """A network's output ``(N, H, W, 2)`` for inputs of ``shape`` ``(N, H, W)``, refused when it is not
    one (a foreign graph) or not finite (a broken graph or checkpoint, or an overflow in fp16): a flow
    of NaN would otherwise pass as a registered answer.

    Raises:
        ProjregError: naming the model (``net.source``).
    """
    source = getattr(net, "source", "the network")
    out = np.asarray(out)
    if out.shape != (*shape, 2):
        raise ProjregError(
            f"{source}: gives an output of shape {list(out.shape)} for inputs of {list(shape)}, not a flow "
            f"[{shape[0]}, {shape[1]}, {shape[2]}, 2]; pass a model written by `projreg train` or `projreg export`"
        )
    bad = ~np.isfinite(out)
    if bad.any():
        raise ProjregError(
            f"{source}: the network's flow is not finite (NaN or Inf) on {bad.any(axis=-1).mean():.1%} of the "
            "pixels; the weights are broken, or fp16 overflowed (try --precision fp32)"
        )
    return out.astype(np.float32, copy=False)


def flows_resized(
    net: Network, pairs: Sequence[tuple[np.ndarray, np.ndarray]], max_side: int, batch_size: int = 1
) -> list[np.ndarray]:
    """The network's flow for each pair, pairs longer than ``max_side`` shrunk for it.

    Args:
        net: a network (module docstring).
        pairs: ``(projected, captured)`` uint8 RGB ``(H, W, 3)`` of one size per pair.
        max_side: the longer side the network sees at most (:func:`~projreg.geometry.frames.shrink`); flows come back on
            each pair's own grid in its pixels (:func:`~projreg.geometry.frames.resize_flow`).
        batch_size: at most this many pairs per network call; only pairs whose network inputs share a
            size are batched together (in order of first appearance).

    Returns:
        float32 ``(H, W, 2)`` per pair, in pair order.
    """
    if batch_size < 1:
        raise ProjregError(f"--batch-size must be >= 1, got {batch_size}")
    small = [(shrink(a, max_side), shrink(b, max_side)) for a, b in pairs]
    by_size: dict[tuple[int, ...], list[int]] = {}
    for i, (a, _) in enumerate(small):
        by_size.setdefault(a.shape, []).append(i)
    flows: list[np.ndarray | None] = [None] * len(pairs)
    for members in by_size.values():
        for start in range(0, len(members), batch_size):
            chunk = members[start : start + batch_size]
            inputs = np.stack([small[i][0] for i in chunk]), np.stack([small[i][1] for i in chunk])
            out = checked_flow(net, net(*inputs), inputs[0].shape[:3])  # [n, h, w, 2]
            for i, flow in zip(chunk, out, strict=True):
                flows[i] = resize_flow(np.asarray(flow, np.float32), pairs[i][0].shape)
    return flows
