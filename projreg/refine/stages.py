"""A stage's candidates made side by side on the refinement's pool (:class:`~projreg.refine.workers.Workers`):
DIS's refinement of every start on every view (:func:`submit`, :func:`gather`), or the direct alignment of
each start, whose polishes and refitted plane are tasks of their own (:func:`aligned`). Each candidate's
score map is made on the thread that made it; the candidates come back in a fixed order, so the answer does
not depend on the threads.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future

from .candidates import Candidate, Start, align_view, aligned_plane, polish, polish_views, refine_start, sift_plane
from .context import PairContext
from .workers import Workers


def stage(ctx: PairContext, workers: Workers, starts: list[Start], views: list[str], direct: bool) -> list[Candidate]:
    """Every start refined on each of ``views`` (:func:`submit`), or, ``direct``, aligned on them
    (:func:`aligned`); each candidate scored."""
    if direct:
        return aligned(ctx, workers, starts, views)
    return gather(ctx, starts, submit(ctx, workers, starts, views))


def submit(ctx: PairContext, workers: Workers, starts: list[Start], views: list[str]) -> list[Future]:
    """DIS's refinement of every start on each of ``views`` (the albedo view from the network's and SIFT's
    starts only), submitted to the pool, views then starts."""
    jobs = [(s, view) for view in views for s in starts if s.H is not None]
    jobs = [(s, view) for s, view in jobs if not (view == "albedo" and s.name == "identity")]
    return [workers.submit(_refined, ctx, workers, *job) for job in jobs]


def gather(ctx: PairContext, starts: list[Start], submitted: list[Future]) -> list[Candidate]:
    """The candidates of what :func:`submit` returned for ``starts``, in a fixed order: the refined
    candidates, then the planes, then SIFT's homography alone."""
    done = [job.result() for job in submitted]
    out = [c for group in done for c in group if not c.plane] + [c for group in done for c in group if c.plane]
    for s in starts:
        if s.name == "sift":
            plane = sift_plane(s)
            ctx.score(plane.key, plane.flow)
            out.append(plane)
    return out


def aligned(ctx: PairContext, workers: Workers, starts: list[Start], views: list[str]) -> list[Candidate]:
    """Every start aligned directly on each of ``views`` side by side on the pool; each alignment's polishes
    are tasks of their own, submitted as it is done, and the refitted planes (the short tasks) after every
    polish, so that the threads finish together. In a fixed order: each alignment followed by its polishes,
    then the planes."""
    jobs = [(s, view) for view in views for s in starts if s.H is not None]
    aligning = [workers.submit(_scored, align_view, ctx, s, view) for s, view in jobs]
    finishing = []
    for (s, view), job in zip(jobs, aligning, strict=True):
        alignment = job.result()
        polishing = [workers.submit(_polished, ctx, workers, s, alignment, on) for on in polish_views(ctx, view)]
        finishing.append((s, alignment, polishing))
    planes = [workers.submit(_scored, aligned_plane, ctx, s, alignment) for s, alignment, _ in finishing]
    out = [c for _, alignment, polishing in finishing for c in [alignment] + [job.result() for job in polishing]]
    return out + [plane for job in planes if (plane := job.result()) is not None]


def _refined(ctx: PairContext, workers: Workers, start: Start, view: str) -> list[Candidate]:
    cands = refine_start(ctx, workers.dis(), start, view)
    for c in cands:
        ctx.ncc(c.key, c.flow)  # the score's map, made on this thread
    return cands


def _polished(ctx: PairContext, workers: Workers, start: Start, alignment: Candidate, view: str) -> Candidate:
    return _scored(polish, ctx, workers.dis(), start, alignment, view)


def _scored(make: Callable[..., Candidate | None], ctx: PairContext, *args) -> Candidate | None:
    """``make(ctx, *args)``, with its score's map made on this thread."""
    cand = make(ctx, *args)
    if cand is not None:
        ctx.ncc(cand.key, cand.flow)
    return cand
