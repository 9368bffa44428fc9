"""The versioned table of 160 transform configurations and per-sample parameter draws.

A configuration is a named point of {geometry family x severity x photometric condition} holding
parameter *ranges*; each sample draws its exact parameters uniformly inside them from its own RNG.
The built-in table is ``8 families x 4 severities x 5 conditions``, with
``id = (family * 4 + severity - 1) * 5 + condition``. A TOML file (``projsynth transforms --toml``
writes the built-in one) can replace it.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path

from ..errors import ProjsynthError
from ..utils.ranges import Ranges

TABLE_VERSION = "builtin-v1"
FAMILIES = ("planar", "lens", "cylinder_convex", "cylinder_concave", "sphere_convex", "sphere_concave", "wave", "bumps")
CONDITIONS = ("studio", "night", "daylight", "translucent", "noisy")
SEVERITIES = (1, 2, 3, 4)


# Geometry common to every family, by severity: how far the camera departs from the projector.
_POSE: dict[int, Ranges] = {
    1: {
        "baseline_deg": (1, 4),
        "roll_deg": (0, 1),
        "aim_px": (0, 5),
        "fov_ratio": (0.98, 1.02),
        "tilt_deg": (0, 6),
        "distance_ratio": (0.95, 1.05),
    },
    2: {
        "baseline_deg": (4, 10),
        "roll_deg": (0.5, 3),
        "aim_px": (4, 16),
        "fov_ratio": (0.93, 1.07),
        "tilt_deg": (4, 14),
        "distance_ratio": (0.9, 1.1),
    },
    3: {
        "baseline_deg": (9, 18),
        "roll_deg": (2, 6),
        "aim_px": (12, 36),
        "fov_ratio": (0.87, 1.13),
        "tilt_deg": (10, 24),
        "distance_ratio": (0.85, 1.15),
    },
    4: {
        "baseline_deg": (16, 28),
        "roll_deg": (4, 10),
        "aim_px": (28, 70),
        "fov_ratio": (0.8, 1.2),
        "tilt_deg": (18, 34),
        "distance_ratio": (0.8, 1.2),
    },
}
_CURVATURE = [(0.1, 0.3), (0.3, 0.6), (0.6, 1.0), (1.0, 1.5)]  # distance / radius
_SHAPE: dict[str, dict[int, Ranges]] = {
    "lens": {
        s: {
            "cam_k1": (0.03 * s, 0.07 * s),
            "cam_k2": (0.0, 0.005 * s),
            "cam_p": (0.0, 0.002 * s),
            "proj_k1": (0.0, 0.02 * s),
        }
        for s in SEVERITIES
    },
    "cylinder": {s: {"curvature": c} for s, c in zip(SEVERITIES, _CURVATURE, strict=True)},
    "sphere": {s: {"curvature": c} for s, c in zip(SEVERITIES, _CURVATURE, strict=True)},
    "wave": {
        s: {"wave_amp": (0.008 * s, 0.016 * s), "wave_freq": (0.6, 1.2), "wave_count": (1, 2)} for s in SEVERITIES
    },
    "bumps": {
        s: {"bump_amp": (0.01 * s, 0.016 * s), "bump_sigma": (0.12, 0.25), "bump_count": (2, 5)} for s in SEVERITIES
    },
}
_COMMON_GEOMETRY: Ranges = {"fov_deg": (42, 56), "principal_jitter_px": (0, 6)}

# Photometry: the paper's compositing (``blend = paper``) and the physical model (``physical``).
# Intensities on the 0-255 scale; alpha, beta, gamma in [0, 1].
_CONDITIONS: dict[str, Ranges] = {
    "studio": {
        "contrast": (0.85, 1.0),
        "brightness": (0, 15),
        "beta": (0.85, 1.0),
        "alpha": (0.9, 1.0),
        "alpha_var": (0, 0.05),
        "gamma": (0.3, 0.5),
        "noise_mu": (-2, 2),
        "noise_sigma": (0.5, 2),
        "ambient": (0.05, 0.15),
        "power": (0.8, 1.0),
        "gain": (0.9, 1.1),
        "response": (2.0, 2.4),
        "vignetting": (0, 0.2),
        "defocus_px": (0, 0.6),
        "shot_noise": (0.002, 0.006),
        "read_noise": (0.5, 1.5),
    },
    "night": {
        "contrast": (0.8, 1.0),
        "brightness": (0, 20),
        "beta": (0.9, 1.0),
        "alpha": (0.9, 1.0),
        "alpha_var": (0, 0.05),
        "gamma": (0.05, 0.2),
        "noise_mu": (-2, 2),
        "noise_sigma": (1, 4),
        "ambient": (0.0, 0.05),
        "power": (0.8, 1.0),
        "gain": (1.2, 2.0),
        "response": (2.0, 2.4),
        "vignetting": (0.1, 0.35),
        "defocus_px": (0, 0.8),
        "shot_noise": (0.004, 0.01),
        "read_noise": (1.5, 4),
    },
    "daylight": {
        "contrast": (0.55, 0.8),
        "brightness": (10, 40),
        "beta": (0.45, 0.7),
        "alpha": (0.85, 1.0),
        "alpha_var": (0, 0.1),
        "gamma": (0.7, 1.0),
        "noise_mu": (-3, 3),
        "noise_sigma": (1, 3),
        "ambient": (0.5, 0.9),
        "power": (0.5, 0.8),
        "gain": (0.6, 0.9),
        "response": (2.0, 2.4),
        "vignetting": (0, 0.2),
        "defocus_px": (0, 0.6),
        "shot_noise": (0.002, 0.006),
        "read_noise": (0.5, 1.5),
    },
    "translucent": {
        "contrast": (0.7, 1.0),
        "brightness": (0, 20),
        "beta": (0.6, 0.9),
        "alpha": (0.35, 0.7),
        "alpha_var": (0.1, 0.3),
        "gamma": (0.3, 0.6),
        "noise_mu": (-2, 2),
        "noise_sigma": (1, 3),
        "ambient": (0.2, 0.4),
        "power": (0.4, 0.7),
        "gain": (0.9, 1.2),
        "response": (2.0, 2.4),
        "vignetting": (0, 0.25),
        "defocus_px": (0, 1.0),
        "shot_noise": (0.002, 0.008),
        "read_noise": (0.5, 2),
    },
    "noisy": {
        "contrast": (0.6, 0.9),
        "brightness": (0, 25),
        "beta": (0.7, 0.95),
        "alpha": (0.8, 1.0),
        "alpha_var": (0, 0.1),
        "gamma": (0.2, 0.6),
        "noise_mu": (-8, 8),
        "noise_sigma": (6, 14),
        "ambient": (0.1, 0.3),
        "power": (0.6, 0.9),
        "gain": (2.0, 4.0),
        "response": (1.8, 2.4),
        "vignetting": (0.1, 0.4),
        "defocus_px": (0.5, 1.5),
        "shot_noise": (0.01, 0.03),
        "read_noise": (3, 8),
    },
}

# Sanity bounds for user tables: every drawn value must stay inside these.
_BOUNDS: Ranges = {
    "baseline_deg": (0, 60),
    "roll_deg": (0, 45),
    "aim_px": (0, 500),
    "fov_ratio": (0.5, 2.0),
    "tilt_deg": (0, 60),
    "distance_ratio": (0.5, 2.0),
    "fov_deg": (10, 120),
    "principal_jitter_px": (0, 100),
    "cam_k1": (0, 1),
    "cam_k2": (0, 1),
    "cam_p": (0, 0.05),
    "proj_k1": (0, 1),
    "curvature": (0, 3),
    "wave_amp": (0, 0.2),
    "wave_freq": (0.1, 5),
    "wave_count": (1, 4),
    "bump_amp": (0, 0.3),
    "bump_sigma": (0.02, 1),
    "bump_count": (1, 12),
    "contrast": (0, 2),
    "brightness": (-128, 128),
    "beta": (0, 1),
    "alpha": (0, 1),
    "alpha_var": (0, 1),
    "gamma": (0, 1),
    "noise_mu": (-64, 64),
    "noise_sigma": (0, 64),
    "ambient": (0, 2),
    "power": (0, 4),
    "gain": (0, 16),
    "response": (1, 3),
    "vignetting": (0, 1),
    "defocus_px": (0, 5),
    "shot_noise": (0, 0.2),
    "read_noise": (0, 32),
}
_FAMILY_KEYS = {
    "planar": (),
    "lens": ("cam_k1", "cam_k2", "cam_p", "proj_k1"),
    "cylinder_convex": ("curvature",),
    "cylinder_concave": ("curvature",),
    "sphere_convex": ("curvature",),
    "sphere_concave": ("curvature",),
    "wave": ("wave_amp", "wave_freq", "wave_count"),
    "bumps": ("bump_amp", "bump_sigma", "bump_count"),
}
_GEOMETRY_KEYS = tuple(_POSE[1]) + tuple(_COMMON_GEOMETRY)
_PHOTOMETRY_KEYS = tuple(_CONDITIONS["studio"])


@dataclass(frozen=True)
class TransformConfig:
    """One row of the table: a named configuration with parameter ranges ``{name: (lo, hi)}``."""

    id: int
    name: str
    family: str
    severity: int
    condition: str
    geometry: Ranges
    photometry: Ranges


@dataclass(frozen=True)
class TransformTable:
    version: str
    configs: tuple[TransformConfig, ...]

    def __len__(self) -> int:
        return len(self.configs)

    def digest(self) -> str:
        """sha256 of the table's canonical JSON: part of every dataset's config hash."""
        text = json.dumps([asdict(c) for c in self.configs], sort_keys=True)
        return hashlib.sha256(f"{self.version}\n{text}".encode()).hexdigest()


def builtin_table() -> TransformTable:
    """The default 160-row table (``TABLE_VERSION``)."""
    configs = []
    for f, family in enumerate(FAMILIES):
        shape_key = family.split("_")[0] if family != "planar" else None
        for s in SEVERITIES:
            geometry = {**_COMMON_GEOMETRY, **_POSE[s], **(_SHAPE[shape_key][s] if shape_key else {})}
            for c, cond in enumerate(CONDITIONS):
                configs.append(
                    TransformConfig(
                        id=(f * len(SEVERITIES) + s - 1) * len(CONDITIONS) + c,
                        name=f"{family}-s{s}-{cond}",
                        family=family,
                        severity=s,
                        condition=cond,
                        geometry={k: (float(a), float(b)) for k, (a, b) in geometry.items()},
                        photometry={k: (float(a), float(b)) for k, (a, b) in _CONDITIONS[cond].items()},
                    )
                )
    return TransformTable(TABLE_VERSION, tuple(configs))


def load_table(path: Path | None) -> TransformTable:
    """The built-in table, or the one in a TOML file (validated; errors name the file and entry)."""
    if path is None:
        return builtin_table()
    try:
        doc = tomllib.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise ProjsynthError(f"{path}: cannot read transform table ({e}); fix the file") from e
    rows = doc.get("transform")
    if not isinstance(rows, list) or not rows:
        raise ProjsynthError(f"{path}: no [[transform]] entries; see `projsynth transforms --toml`")
    configs = [_parse_row(path, i, row) for i, row in enumerate(rows)]
    if sorted(c.id for c in configs) != list(range(len(configs))):
        raise ProjsynthError(f"{path}: transform ids must be 0..{len(configs) - 1}, each once")
    configs.sort(key=lambda c: c.id)
    return TransformTable(str(doc.get("version", Path(path).stem)), tuple(configs))


# The fields of a [[transform]] entry: (required, type, what it must be)
_ROW_FIELDS = {
    "id": (True, int, "an integer"),
    "family": (True, str, "a string"),
    "geometry": (True, dict, "a table of ranges ([transform.geometry])"),
    "photometry": (True, dict, "a table of ranges ([transform.photometry])"),
    "name": (False, str, "a string"),
    "severity": (False, int, "an integer"),
    "condition": (False, str, "a string"),
}


def _parse_row(path: Path, i: int, row: object) -> TransformConfig:
    """One ``[[transform]]`` entry; every error names the file, the entry (``#i``, 0-based) and the field."""
    where = f"{path}: transform #{i}"
    if not isinstance(row, dict):
        raise ProjsynthError(f"{where}: expected a [[transform]] table, got {row!r:.40}")
    missing = [k for k, (required, _, _) in _ROW_FIELDS.items() if required and k not in row]
    if missing:
        raise ProjsynthError(
            f"{where}: missing key(s) {', '.join(missing)}; each entry needs id, family, geometry, photometry"
        )
    for key, (_, kind, what) in _ROW_FIELDS.items():
        if key in row and (not isinstance(row[key], kind) or isinstance(row[key], bool)):
            raise ProjsynthError(f"{where}: {key} must be {what}, got {row[key]!r:.40}")
    family = row["family"]
    if family not in FAMILIES:
        raise ProjsynthError(f"{where}: unknown family {family!r}; choose from {', '.join(FAMILIES)}")
    geometry = {k: _range(f"{where} geometry", k, v) for k, v in row["geometry"].items()}
    photometry = {k: _range(f"{where} photometry", k, v) for k, v in row["photometry"].items()}
    missing = [k for k in _GEOMETRY_KEYS + _FAMILY_KEYS[family] if k not in geometry]
    missing += [k for k in _PHOTOMETRY_KEYS if k not in photometry]
    if missing:
        raise ProjsynthError(f"{where} ({family}): missing ranges {', '.join(missing)}")
    return TransformConfig(
        row["id"],
        row.get("name", f"t{row['id']}"),
        family,
        row.get("severity", 0),
        row.get("condition", "custom"),
        geometry,
        photometry,
    )


def _range(where: str, key: str, value: object) -> tuple[float, float]:
    if key not in _BOUNDS:
        raise ProjsynthError(f"{where}: unknown parameter {key!r}")
    numbers = isinstance(value, list) and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    if not (numbers and len(value) == 2):
        raise ProjsynthError(f"{where}: {key} must be a [low, high] pair of numbers, got {value!r:.40}")
    lo, hi = float(value[0]), float(value[1])
    blo, bhi = _BOUNDS[key]
    if not (blo <= lo <= hi <= bhi):
        raise ProjsynthError(f"{where}: {key} = [{lo}, {hi}] must satisfy {blo} <= low <= high <= {bhi}")
    return lo, hi


def table_to_toml(table: TransformTable) -> str:
    """Serialise a table in the format :func:`load_table` reads."""
    lines = [f'version = "{table.version}"', ""]
    for c in table.configs:
        lines += [
            "[[transform]]",
            f"id = {c.id}",
            f'name = "{c.name}"',
            f'family = "{c.family}"',
            f"severity = {c.severity}",
            f'condition = "{c.condition}"',
            "[transform.geometry]",
        ]
        lines += [f"{k} = [{a!r}, {b!r}]" for k, (a, b) in c.geometry.items()]
        lines += ["[transform.photometry]"]
        lines += [f"{k} = [{a!r}, {b!r}]" for k, (a, b) in c.photometry.items()]
        lines.append("")
    return "\n".join(lines)


def parse_selection(spec: str | None, n: int) -> list[int]:
    """``"0-15"``, ``"0,5,9"``, ``"0-3,10"``, ``"all"`` or None (all) -> sorted unique ids in ``[0, n)``.

    An empty string is refused rather than read as "all" (an unset shell variable should not silently
    generate the whole table).
    """
    if spec is None or spec.strip() == "all":
        return list(range(n))
    if not spec.strip():
        raise ProjsynthError("--transforms: empty; give ids such as 0-15 or 0,5,9, or all")
    ids: set[int] = set()
    for part in spec.split(","):
        part = part.strip()
        try:
            lo, _, hi = part.partition("-")
            a, b = int(lo), int(hi) if hi else int(lo)
        except ValueError:
            raise ProjsynthError(f"--transforms: cannot parse {part!r}; use e.g. 0-15 or 0,5,9") from None
        if not (0 <= a <= b < n):
            raise ProjsynthError(f"--transforms: {part!r} is outside 0-{n - 1}")
        ids.update(range(a, b + 1))
    return sorted(ids)


