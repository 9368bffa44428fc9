"""One pair's search so far (:class:`Search`): what :class:`~projreg.refine.refiner.GeometricRefiner`'s
stages read and write, and the winner's re-alignment started on the pool ahead of its verification."""

from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass
from threading import Event

import numpy as np

from ..geometry.align import Stopped
from .candidates import Candidate, Start, realign
from .context import PairContext
from .workers import Workers


@dataclass
class Search:
    """One pair's search so far: its context, the network's start, the candidates in the order tried,
    their scores, the stages run, the periodicity map, the current winner and its confidence, the
    winner's re-alignment when it was started ahead (:meth:`realign_ahead`) with the event that stops it,
    and the handedness check running beside the search."""

    ctx: PairContext
    network: Start
    cands: list[Candidate]
    scores: dict[str, float]
    stages: list[str]
    repeats: np.ndarray | None = None
    best: Candidate | None = None
    conf: np.ndarray | None = None
    ahead: tuple[Candidate, Future, Event] | None = None
    mirror: Future | None = None  # the pair's handedness (:mod:`~projreg.refine.handedness`), on the pool

    def claimed(self) -> float:
        """The share of the visible texture the winner claims (:meth:`.PairContext.claimed_share`)."""
        return self.ctx.claimed_share(self.conf, self.best.flow)

    def realign_ahead(self, workers: Workers) -> None:
        """Start the winner's re-alignment on the pool (the one of an earlier winner stopped); one already
        started for this winner goes on."""
        if self.ahead is not None and self.ahead[0] is self.best:
            return
        self.drop_ahead()
        stop = Event()
        self.ahead = (self.best, workers.submit(_realigned, self.ctx, self.best, stop), stop)

    def drop_ahead(self) -> None:
        """Stop the re-alignment started ahead, if any (within one alignment step), and forget it."""
        if self.ahead is not None:
            self.ahead[2].set()
            self.ahead[1].cancel()
            self.ahead = None


def _realigned(ctx: PairContext, best: Candidate, stop: Event) -> Candidate | None:
    """``best``'s re-alignment (:func:`~projreg.refine.candidates.realign`); None once ``stop`` is set."""
    try:
        return realign(ctx, best, stop.is_set)
    except Stopped:
        return None
