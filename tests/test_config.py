import pytest

from crawler import config
from crawler.errors import BadConfig, BadGeometry

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


def test_contract_keys_load_and_derive_thesis_geometry(tmp_path):
    cfg = config.load(write(tmp_path, CONTRACT))
    s = cfg.summary()
    assert s["camera_height_m"] == pytest.approx(0.2256, abs=5e-5)
    assert s["roi"] == [300, 360, 360, 360]           # square under the centre row
    assert s["m_per_px_eq31"] == pytest.approx(0.00021067, rel=1e-4)
    assert s["method"] == "cylinder"


def test_height_given_directly_and_roi_and_overrides(tmp_path):
    text = CONTRACT.replace("camera_offset_m = 0.054", "height_m = 0.2")
    text = text.replace('method = "cylinder"', 'method = "plane"\nroi = [100, 400, 200, 200]')
    cfg = config.load(write(tmp_path, text), ["mount.tilt_deg=24", "odometry.method=pixel"])
    g = cfg.geometry()
    assert g.mount.height_m == 0.2 and g.roi == (100, 400, 200, 200)
    assert g.mount.tilt_deg == pytest.approx(24) and g.projection.name == "pixel"


@pytest.mark.parametrize("text,match", [
    ("[camera]\nwidht = 5\n", r"unknown key \[camera\] widht"),
    ("[camera]\nwidth = 'big'\n", r"\[camera\] width = 'big' must be an integer"),
    ("[cam]\nwidth = 5\n", "unknown key or section 'cam'"),
    ("[odometry]\nmethod = 'magic'\n", "method = 'magic'"),
    ("[odometry]\nroi = [0, 0, 2000, 10]\n", r"roi = \[0, 0, 2000, 10\]"),
    ("[camera]\ndistortion = [1, 2]\n", "distortion"),
    ("[mount]\ntilt_deg = 85\n", "tilt_deg = 85"),
    ("name = 'bad name'\n", "name = 'bad name'"),
    ("[odometry\n", "not valid TOML"),
])
def test_bad_values_name_the_key(tmp_path, text, match):
    with pytest.raises(BadConfig, match=match):
        config.load(write(tmp_path, text))


def test_impossible_geometry_refused_at_load(tmp_path):
    with pytest.raises(BadGeometry, match="car_width_m = 0.35"):
        config.load(None, ["mount.car_width_m=0.35"])
    with pytest.raises(BadGeometry, match="tilt_deg = 75"):
        config.load(None, ["mount.tilt_deg=75"])


def test_missing_file_and_bad_override():
    with pytest.raises(BadConfig, match="not found"):
        config.load("/no/such/crawlerd.toml")
    with pytest.raises(BadConfig, match="section.key=value"):
        config.load(None, ["tilt"])
