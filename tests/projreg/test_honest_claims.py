"""What a registration claims when it should claim nothing, or little: a photo of another picture, a
mirrored camera, a faint low-texture picture on a strongly textured wall (issue 57, items 1-3); in every
quality, through the API a user calls. Pictures: scikit-image's; truth: a rig written in bench/."""

import importlib.util
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from projreg.api import Registrar

skimage_data = pytest.importorskip("skimage.data")
pytestmark = pytest.mark.slow
SIZE = (256, 192)  # W x H, the size
MOST = 0.01  # "no claim": at most this share of the frame


def picture(name: str, size: tuple[int, int] = SIZE) -> np.ndarray:
    image = np.asarray(getattr(skimage_data, name)())
    image = image.astype(np.uint8) * 255 if image.dtype == bool else image
    if image.dtype != np.uint8:  # the phantom: floats in [0, 1]
        image = (255 * (image - image.min()) / max(float(image.max() - image.min()), 1e-9)).astype(np.uint8)
    image = np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image[..., :3]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA)


@pytest.fixture(scope="module", params=["fast", "balanced", "accurate"])
def registrar(request):
    return Registrar(quality=request.param)


@pytest.mark.parametrize(
    "name, flip",
    [("coins", "x"), ("coins", "y"), ("brick", "x"), ("page", "y"), ("retina", "x"), ("clock", "x")],
)
def test_a_mirrored_camera_claims_nothing(registrar, name, flip):
    projected = picture(name)
    captured = np.ascontiguousarray(projected[:, ::-1] if flip == "x" else projected[::-1])
    reg = registrar.register(projected, captured)
    assert reg.claimed.mean() <= MOST, (name, flip, reg.claimed.mean())
    if not reg.registered and reg.reason.startswith("mirrored"):
        assert "flip the captured images" in reg.reason


@pytest.mark.parametrize("name", ["coins", "horse", "clock"])
def test_a_mirrored_camera_turned_a_quarter_claims_nothing(registrar, name):
    """The capture transposed (a mirror about the diagonal) and resized back to the projector's aspect, as
    a portrait camera's frames are: a 1.78x anisotropic stretch on top of the mirror. The clock's face has
    few keypoints (26 mirrored SIFT matches against 5 direct): its mirror is weighed by its score."""
    projected = picture(name)
    captured = cv2.resize(np.ascontiguousarray(projected.transpose(1, 0, 2)), SIZE, interpolation=cv2.INTER_AREA)
    reg = registrar.register(projected, captured)
    assert reg.claimed.mean() <= MOST, (name, reg.claimed.mean())


def test_a_camera_turned_upside_down_is_not_a_mirror(registrar):
    projected = picture("coins")
    reg = registrar.register(projected, np.ascontiguousarray(projected[::-1, ::-1]))
    assert reg.registered, reg.reason  # fast, without the identity's and SIFT's starts, claims a part


@pytest.mark.parametrize(
    "projected, captured",
    [("astronaut", "coffee"), ("camera", "horse"), ("coins", "page"), ("brick", "grass"), ("retina", "moon")],
)
def test_a_photo_of_another_picture_claims_nothing(registrar, projected, captured):
    reg = registrar.register(picture(projected), picture(captured))
    assert reg.claimed.mean() <= MOST, (projected, captured, reg.claimed.mean())


@pytest.mark.parametrize(
    "projected, captured, size",
    [("shepp_logan_phantom", "logo", (512, 384)), ("logo", "coins", (512, 384)), ("colorwheel", "astronaut", SIZE)],
)
def test_a_chance_match_of_curves_is_not_confirmed(registrar, projected, captured, size):
    """Pictures of curves and flat regions, photographed as another picture: a flexible warp carried a few of
    their curves onto the other's and every local check passed (balanced claimed 19.7 %, 8.4 % and 10.8 %);
    aligned again over the whole frame the claim moves away, and nothing is claimed."""
    reg = registrar.register(picture(projected, size), picture(captured, size))
    assert reg.claimed.mean() <= MOST, (projected, captured, reg.claimed.mean(), reg.reason)
    if reg.reason.startswith("unconfirmed"):  # what to do when the picture is the right one
        assert "structured-light pass" in reg.reason


@pytest.fixture(scope="module")
def rig():
    path = Path(__file__).parents[2] / "bench" / "external_rig.py"
    spec = importlib.util.spec_from_file_location("external_rig", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["external_rig"] = module  # its dataclass looks its module up by name
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name, wall", [("shepp_logan_phantom", "plaid"), ("page", "brick"), ("moon", "stripes")])
def test_a_faint_picture_on_a_textured_wall_claims_only_what_holds(registrar, rig, name, wall):
    """The projection faint (room light as bright as the projector) under the wall's own strong pattern:
    whatever is claimed is within 1.5 px on average (issue 57's target), the truth the rig's."""
    h, w = 288, 384
    pair = rig.render(name, rig.picture(name, h, w), 0, seed=7, force={"albedo": wall, "ambient": 1.0})
    reg = registrar.register(pair.projected, pair.captured)
    claimed = reg.claimed & pair.valid
    if claimed.any():
        error = np.linalg.norm(reg.flow - pair.flow, axis=-1)[claimed]
        assert error.mean() <= 1.5, (name, wall, float(claimed.mean()), float(error.mean()))


@pytest.mark.parametrize("quality", ["balanced", "accurate"])
def test_curves_on_a_bumpy_surface_are_claimed_only_where_something_pins_them(rig, quality):
    """The Shepp-Logan phantom (ellipses and a few small blobs) on a dozen bumps 4-9 px high: its
    ellipses' pixels slide along their edges without failing a local check, and the span test over four
    radii sees both directions on each ellipse. What is claimed is within 1.5 px on average, and the
    neighbourhoods of the blobs still are (without the pinning rule `balanced` claimed 34 % of the frame
    2.4 px off). `fast`'s answer has no fine level to bend with: known limit, docs/model.md."""
    h, w = 288, 384
    name = "shepp_logan_phantom"
    pair = rig.render(name, rig.picture(name, h, w), 0, 7, {"shape": "bumps", "albedo": "plain", "ambient": 0.08})
    reg = Registrar(quality=quality).register(pair.projected, pair.captured)
    claimed = reg.claimed & pair.valid
    error = np.linalg.norm(reg.flow - pair.flow, axis=-1)[claimed]
    assert claimed.mean() > 0.05 and error.mean() <= 1.5, (float(claimed.mean()), float(error.mean()))


@pytest.mark.parametrize("quality, name", [("accurate", "horse"), ("fast", "text"), ("fast", "astronaut-left")])
def test_the_striped_sheets_hardest_pictures_claim_only_what_holds(rig, quality, name):
    """The external rig's stripes run (a sheet bent with a 180-360 px period, painted stripes, a gamma camera,
    no room light), its pairs where a quality claimed pixels 1.5-1.7 px off on average: `accurate`'s horse,
    whose DIS-refined answers score above the truth on the stripes (the first stage's aligned answer is now
    kept beside them), and `fast`'s text and one-sided astronaut, whose small claims at 256 px are now verified
    at the pair's own size. Whatever is claimed is within 1.5 px on average."""
    h, w = 384, 512
    contents = rig.contents(h, w)
    index = [n for n, _ in contents].index(name)
    force = {"shape": "bend", "albedo": "stripes", "response": "gamma", "ambient": 0.0}
    pair = rig.render(name, contents[index][1], index, 2026, force)
    reg = Registrar(quality=quality).register(pair.projected, pair.captured)
    claimed = reg.claimed & pair.valid
    if claimed.any():
        error = np.linalg.norm(reg.flow - pair.flow, axis=-1)[claimed]
        assert error.mean() <= 1.5, (quality, name, float(claimed.mean()), float(error.mean()))
