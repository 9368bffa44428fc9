"""Reflected Gray-code bits photographed with their inverses: the stripe index, and the bits' agreement.

Shared by both Gray-code decoders (``graycode`` in :mod:`projsynth.structured.decode`, ``opencv-graycode``
in :mod:`projsynth.structured.edges`). A bit is photographed twice, pattern and inverse; ``diff`` is
pattern minus inverse, ``(Hc, Wc)`` float32, positive where the bit is 1. Bit ``b`` (0: least
significant) of stripe ``n`` is bit ``b`` of ``n ^ (n >> 1)``; stripe ``n`` covers projector positions
``[n * stripe - 0.5, (n + 1) * stripe - 0.5)`` (pixel centres at integers).
"""

from __future__ import annotations

import numpy as np

BIT_MARGIN_PX = 2.0  # projector px from a Gray bit's own stripe edge beyond which the bit must be clear


def gray_stripe(bits: list[np.ndarray]) -> np.ndarray:
    """The stripe index per camera pixel, ``(Hc, Wc)`` int64, from ``bits[b]`` (``diff`` of bit ``b``)."""
    gray = np.zeros(bits[0].shape, np.int64)
    for b, diff in enumerate(bits):
        gray |= (diff > 0).astype(np.int64) << b
    binary, shift = gray.copy(), 1
    while shift < len(bits):
        binary ^= binary >> shift
        shift <<= 1
    return binary


def bits_agree(bits: list[np.ndarray], pos: np.ndarray, stripe: int, floor: np.ndarray) -> np.ndarray:
    """Where every Gray-code bit far from its own stripe edge says what the position ``pos`` implies.

    Args:
        bits: ``bits[b]`` is ``diff`` of bit ``b``, ``(Hc, Wc)``.
        pos: ``(Hc, Wc)`` projector position (px) each camera pixel is believed to see.
        stripe: projector px per stripe (1: every pixel its own code).
        floor: ``(Hc, Wc)``: the least ``|diff|`` of a clear bit.

    Returns:
        ``(Hc, Wc)`` bool. Bit ``b`` flips at ``n * stripe - 0.5`` with ``n = 2^b (mod 2^(b+1))``; more
        than ``BIT_MARGIN_PX`` from those it must have the expected sign and ``|diff| >= floor``. A
        noise-flipped bit or a wrong position fails here instead of moving the position by whole stripes.
    """
    n = np.floor((pos + 0.5) / stripe).astype(np.int64)
    code = n ^ (n >> 1)
    agree = np.ones(pos.shape, bool)
    for b, diff in enumerate(bits):
        t = (pos + 0.5) / stripe - 2**b
        edge = np.abs(t - 2 ** (b + 1) * np.rint(t / 2 ** (b + 1))) * stripe
        expected = np.where((code >> b) & 1 == 1, 1.0, -1.0)
        agree &= (edge <= BIT_MARGIN_PX) | (diff * expected >= floor)
    return agree
