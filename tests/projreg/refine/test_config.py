"""The refinement's configuration: sections with one meaning per field, checked, and the quality dial."""

import pytest

from projreg import ProjregError
from projreg.refine.config import ACCURATE, BALANCED, DEFAULT_QUALITY, FAST, QUALITIES, SEARCH, RefineConfig, quality


@pytest.mark.parametrize(
    ("sections", "message"),
    [
        ({"surface": {"grid": (3, 8)}}, "grids"),
        ({"surface": {"robust_px": 0}}, "surface.robust_px"),
        ({"images": {"contrast_sigma": 0}}, "images.contrast_sigma"),
        ({"images": {"albedo_window": 4}}, "albedo_window"),
        ({"images": {"max_side": 16}}, "images.max_side must be >= 32"),
        ({"search": {"grow_below": 1.5}}, "search.grow_below"),
        ({"search": {"escalate_below": -0.1}}, "search.escalate_below"),
        ({"search": {"settle_at": 1.5}}, "search.settle_at"),
        ({"search": {"keep_direct_at": -0.5}}, "search.keep_direct_at"),
        ({"images": {"verify_full_below": 2.0}}, "images.verify_full_below"),
        ({"search": {"workers": 0}}, "search.workers"),
        ({"search": {"sift_side": 16}}, "search.sift_side"),
        ({"selection": {"plane_margin": -0.1}}, "selection.plane_margin"),
        ({"selection": {"plane_agree_px": -1.0}}, "selection.plane_agree_px"),
        ({"confidence": {"radius": 0}}, "confidence.radius"),
        ({"align": {"cauchy": 0.0}}, "align.cauchy must be > 0"),
        (
            {"align": {"detail_steps": 4, "narrow_steps": 5}},
            r"align.narrow_steps must be in \[0, align.detail_steps = 4\]",
        ),
        ({"confidence": {"registered_windows": -1.0}}, "confidence.registered_windows"),
        ({"align": {"views": ("normalized",)}}, "align.views names views normalised, plain, albedo"),
        ({"align": {"polish": ("plane",)}}, "align.polish names views"),
        ({"search": {"first_views": ("albedos",)}}, "search.first_views names views"),
        ({"align": {"direct": True, "views": ()}}, "align.views must name one view or more"),
        ({"align": {"direct": True, "views": ("plain",)}, "images": {"plain": False}}, "plain needs images.plain"),
    ],
)
def test_a_bad_value_is_refused_naming_its_section_and_field(sections, message):
    with pytest.raises(ProjregError, match=message):
        RefineConfig().with_sections(**sections)


def test_the_quality_dial_orders_the_settings_from_latency_to_accuracy():
    assert list(QUALITIES) == ["fast", "balanced", "accurate"] and DEFAULT_QUALITY == "balanced"
    assert [q.refine for q in QUALITIES.values()] == [FAST, BALANCED, ACCURATE]
    assert SEARCH == RefineConfig()  # the field defaults are the full search, in one stage
    # accurate: balanced's first stage, then always the full search beside it (its candidates kept where
    # balanced would have stopped), every pair at its own size
    assert ACCURATE.align == BALANCED.align and ACCURATE.search.escalate_below == 1
    assert ACCURATE.search.keep_direct_at == BALANCED.search.escalate_below and BALANCED.search.keep_direct_at == 1
    # the most the network sees, escalations included: 256, 512, 1024 px
    sides = [q.finer_side() or q.network_side for q in QUALITIES.values()]
    assert sides == sorted(sides) and len(set(sides)) == 3, sides
    assert ACCURATE.images.max_side is None  # only accurate searches every pair at its own size ...
    assert FAST.images.max_side < BALANCED.images.max_side and BALANCED.images.verify_full  # ... balanced verifies
    assert not FAST.search.identity and not FAST.search.sift
    assert BALANCED.search.escalate_below < 1 <= ACCURATE.search.escalate_below and BALANCED.align.direct
    balanced = QUALITIES["balanced"]  # the network at 256 px first, at up to 512 where the search escalates
    assert balanced.finer_side(1024) == 512 and balanced.finer_side(200) is None and balanced.finer_side(400) == 400
    assert balanced.finer_side() == 512  # no user cap: the quality's own
    assert QUALITIES["accurate"].finer_side() == 1024 and QUALITIES["accurate"].finer_side(200) is None
    assert QUALITIES["fast"].finer_side() is None
    with pytest.raises(ProjregError, match="--quality 'quick': expected one of fast, balanced, accurate"):
        quality("quick")


def test_with_sections_replaces_only_the_named_fields():
    cfg = ACCURATE.with_sections(search={"sift": False}, surface={"detail": False})
    assert not cfg.search.sift and cfg.search.identity and not cfg.surface.detail
    assert cfg.surface.grid == ACCURATE.surface.grid and cfg.images == ACCURATE.images
