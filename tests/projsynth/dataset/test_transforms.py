import numpy as np
import pytest

from projsynth import ProjsynthError
from projsynth.dataset.transforms import CONDITIONS, FAMILIES, builtin_table, load_table, parse_selection, table_to_toml
from projsynth.utils.ranges import draw


def test_builtin_table_has_160_distinct_configs_in_id_order():
    t = builtin_table()
    assert len(t) == 160 == len(FAMILIES) * 4 * len(CONDITIONS)
    assert [c.id for c in t.configs] == list(range(160))
    assert len({c.name for c in t.configs}) == 160
    assert t.configs[37].name == "lens-s4-daylight"  # id = (family*4 + severity-1)*5 + condition


def test_draws_stay_inside_ranges_and_are_reproducible():
    cfg = builtin_table().configs[123]
    a = draw(np.random.default_rng(3), cfg.photometry)
    b = draw(np.random.default_rng(3), cfg.photometry)
    assert a == b
    for k, v in a.items():
        lo, hi = cfg.photometry[k]
        assert lo <= v <= hi


def test_toml_round_trip(tmp_path):
    t = builtin_table()
    path = tmp_path / "table.toml"
    path.write_text(table_to_toml(t))
    u = load_table(path)
    assert u.configs == t.configs and u.version == t.version and u.digest() == t.digest()


@pytest.mark.parametrize(("spec", "ids"), [(None, list(range(160))), ("0-3", [0, 1, 2, 3]), ("9,0,5", [0, 5, 9]),
                                           ("0-2,2-3", [0, 1, 2, 3])])
def test_parse_selection(spec, ids):
    assert parse_selection(spec, 160) == ids


@pytest.mark.parametrize("spec", ["0-160", "a", "3-1", "-1", "1-2-3"])
def test_parse_selection_rejects(spec):
    with pytest.raises(ProjsynthError, match="--transforms"):
        parse_selection(spec, 160)


def test_bad_range_in_table_names_file_and_key(tmp_path):
    text = table_to_toml(builtin_table()).replace("beta = [0.85, 1.0]", "beta = [0.9, 0.2]", 1)
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ProjsynthError, match=r"bad\.toml.*beta"):
        load_table(path)
