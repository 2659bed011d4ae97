import pytest

from crawler import settings as S
from crawler.errors import BadConfig, BadGeometry
from crawler.measurement import build_odometer, describe, recording_camera, thesis_roi

CONTRACT = """
name = "crawler1"
[camera]
width = 960
height = 720
vfov_deg = 37.16
hfov_deg = 53.50
readout_ms = 0.0
[mount]
pipe_diameter_m = 0.30
car_width_m = 0.151
camera_offset_m = 0.054
tilt_deg = 0.0
[odometry]
method = "cylinder"
"""


def write(tmp_path, text):
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def recording(settings):
    cam = recording_camera(settings.camera)
    return cam, thesis_roi(cam.width, cam.height)


def test_contract_keys_load_and_derive_thesis_geometry(tmp_path):
    s = describe(*((st := S.load(write(tmp_path, CONTRACT))),) + recording(st))
    assert s["camera_height_m"] == pytest.approx(0.2256, abs=5e-5)
    assert s["roi"] == [300, 360, 360, 360]           # square under the centre row
    assert s["m_per_px_eq31"] == pytest.approx(0.00021067, rel=1e-4)
    assert s["method"] == "cylinder"


def test_height_given_directly_and_roi_and_overrides(tmp_path):
    text = CONTRACT.replace("camera_offset_m = 0.054", "height_m = 0.2")
    text = text.replace('method = "cylinder"', 'method = "plane"\nroi = [100, 400, 200, 200]')
    st = S.load(write(tmp_path, text), ["mount.tilt_deg=24", "odometry.method=pixel"])
    odo = build_odometer(st, *recording(st))
    assert odo.projection.mount.height_m == 0.2 and odo.roi == (100, 400, 200, 200)
    assert odo.projection.mount.tilt_deg == pytest.approx(24) and odo.projection.name == "pixel"


def test_flags_set_typed_fields_directly_and_are_validated_in_the_same_place():
    st = S.load(None, [], {"mount.tilt_deg": 12.5, "zenoh.listen": ("tcp/127.0.0.1:7447",)})
    assert st.mount.tilt_deg == 12.5 and st.zenoh.listen == ("tcp/127.0.0.1:7447",)
    assert isinstance(S.load(None, ["camera.fps=50"]).camera.fps, float)     # an int in TOML is a number
    with pytest.raises(BadConfig, match=r"\[mount\] tilt_deg = 95.0 must be between -80 and 80"):
        S.load(None, [], {"mount.tilt_deg": 95.0})
    with pytest.raises(BadConfig, match=r"\[leds\] brightness = 1.5 must be between 0 and 1"):
        S.Settings().with_values({"leds.brightness": 1.5})


@pytest.mark.parametrize("text,match", [
    ("[camera]\nwidht = 5\n", r"unknown key \[camera\] widht"),
    ("[camera]\nwidth = 'big'\n", r"\[camera\] width = 'big' must be an integer"),
    ("[cam]\nwidth = 5\n", "unknown key or section 'cam'"),
    ("[odometry]\nmethod = 'magic'\n", "method = 'magic'"),
    ("[camera]\ndistortion = [1, 2]\n", "distortion"),
    ("[mount]\ntilt_deg = 85\n", "tilt_deg = 85"),
    ("name = 'bad name'\n", "name = 'bad name'"),
    ("[odometry\n", "not valid TOML"),
    ("[camera]\nline_time_us = 30.0\n", r"\[camera\] line_time_us was renamed; use \[camera\] readout_ms"),
    ("[leds]\nfrequency_hz = 20000\n", r"frequency_hz = 20000.0 must be between 0.1 and 10000 Hz"),
    ("[zenoh]\nlisten = ['tcp/0.0.0.0:99999']\n", "port 99999 must be 1..65535"),
    ("[zenoh]\nconnect = ['not-an-endpoint']\n", "Endpoints must be of the form"),
    ("[zenoh]\nmode = 'server'\n", "mode = 'server' must be one of peer, client, router"),
    ("[camera]\nexposure_us = 20000\nfps = 90\n", "longer than a frame"),
])
def test_bad_values_name_the_key(tmp_path, text, match):
    with pytest.raises(BadConfig, match=match):
        S.load(write(tmp_path, text))


def test_roi_outside_the_frame_is_refused_when_the_model_is_built(tmp_path):
    st = S.load(write(tmp_path, "[odometry]\nroi = [0, 0, 2000, 10]\n"))
    with pytest.raises(BadConfig, match=r"roi = \[0, 0, 2000, 10\] must lie inside the 960x720 frame"):
        build_odometer(st, *recording(st))


def test_impossible_geometry_refused():
    with pytest.raises(BadGeometry, match="car_width_m = 0.35"):
        S.load(None, ["mount.car_width_m=0.35"])
    st = S.load(None, ["mount.tilt_deg=75"])
    with pytest.raises(BadGeometry, match="tilt_deg = 75"):
        build_odometer(st, *recording(st))


def test_missing_file_and_bad_override():
    with pytest.raises(BadConfig, match="not found"):
        S.load("/no/such/crawlerd.toml")
    with pytest.raises(BadConfig, match="section.key=value"):
        S.load(None, ["tilt"])
