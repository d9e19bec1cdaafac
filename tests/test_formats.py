"""ROS camera_info, Kalibr camchain and mrcal .cameramodel in and out (issue 26 item 1).

Round trips per format and lens model; each format checked against what its own project's reader expects
(camera_calibration_parsers' parse_yml.cpp, Kalibr's ConfigReader.py, mrcal's cameramodel.py: docs/FORMATS.md), and
by mrcal's own reader where mrcal is installed; an imported calibration measured with like the original.
"""

from __future__ import annotations

import json
import subprocess

import cv2
import numpy as np
import pytest
import yaml

from stereo_bench.cli import main
from stereo_bench.vision.calibio import read_calibration, write_calibration
from stereo_bench.vision.calibrate import StereoCalibration
from stereo_bench.vision.formats import (
    FormatError,
    UnrepresentableLens,
    export_texts,
    import_texts,
    projection_change_px,
)
from stereo_bench.vision.mrcal_bridge import mrcal_python
from stereo_bench.vision.rectify import rectify
from tests.real_data import OPENCV_FORMAT, OPENCV_SAMPLE
from tests.test_cli_vision import run

D5 = [-0.051, 0.021, 0.0012, -0.0008, 0.0]
LENSES = {  # our lens models' distortion vectors (as calibrate writes them: D of 5, 8 or 12)
    "opencv4": (D5, [-0.04, 0.012, -0.0003, 0.0006, 0.0]),
    "fixed-aspect": (D5, [-0.04, 0.012, -0.0003, 0.0006, 0.0]),
    "opencv5": ([-0.051, 0.021, 0.0012, -0.0008, 0.013], [-0.04, 0.012, -0.0003, 0.0006, -0.007]),
    "rational": ([0.3, -0.2, 0.001, -0.0004, 0.05, 0.35, -0.15, 0.06], [0.28, -0.19, 0.0, 0.0003, 0.04, 0.33, -0.1,
                                                                         0.05]),
    "thin-prism": ([-0.05, 0.02, 0.001, 0.0, 0, 0, 0, 0, 0.0011, -0.0002, 0.0009, 0.0003],
                   [-0.04, 0.01, 0.0, 0.0004, 0, 0, 0, 0, -0.0007, 0.0001, 0.0005, -0.0002]),
}
#: Which formats hold which of our lens models exactly.
EXACT = {"ros": {"opencv4", "fixed-aspect", "opencv5", "rational"}, "kalibr": {"opencv4", "fixed-aspect"},
         "mrcal": set(LENSES)}


def calibration(lens: str = "opencv4") -> StereoCalibration:
    K1 = np.array([[1333.25, 0, 961.5], [0, 1331.75 if lens != "fixed-aspect" else 1333.25, 541.25], [0, 0, 1]])
    K2 = np.array([[1329.5, 0, 957.0], [0, 1328.0 if lens != "fixed-aspect" else 1329.5, 538.5], [0, 0, 1]])
    angle = np.radians(4.0)
    R = cv2.Rodrigues(np.array([0.002, -angle, 0.001]))[0]
    D1, D2 = LENSES[lens]
    return StereoCalibration(K1=K1, D1=np.array([D1]), K2=K2, D2=np.array([D2]), R=R, T=np.array([-99.6, 0.31, 6.9]),
                             image_size=(1920, 1080), rms_px=0.2, mode="joint", lens_model=lens)


def assert_same(loaded: StereoCalibration, calib: StereoCalibration, *, rtol: float = 1e-12) -> None:
    for name in ("K1", "D1", "K2", "D2", "R", "T"):
        a, b = np.asarray(getattr(loaded, name)), np.asarray(getattr(calib, name))
        assert a.shape == b.shape, name
        # A rotation's elements are bounded by 1 and round absolutely: through a Rodrigues vector (mrcal) or the
        # rectifications' product (ROS) a small off-diagonal element keeps ~3e-14 absolute, not 1e-12 of itself.
        atol = 1e-13 if name == "R" else 1e-14 * max(1.0, float(np.max(np.abs(b))))
        np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, err_msg=name)
    assert loaded.image_size == calib.image_size
    assert loaded.lens_model == calib.lens_model


def texts_of(exported) -> list[tuple[str, str]]:
    order = {"left.yaml": 0, "right.yaml": 1, "left.cameramodel": 0, "right.cameramodel": 1, "camchain.yaml": 0}
    return sorted(exported.files.items(), key=lambda item: order[item[0]])


@pytest.mark.parametrize("fmt", ["ros", "kalibr", "mrcal"])
@pytest.mark.parametrize("lens", list(LENSES))
@pytest.mark.parametrize("unit_mm", [1000.0, 1.0])
def test_round_trip_is_exact_where_the_format_holds_the_lens(fmt, lens, unit_mm):
    calib = calibration(lens)
    if lens not in EXACT[fmt]:
        with pytest.raises(UnrepresentableLens, match="--lossy refits"):
            export_texts(calib, fmt, unit_mm=unit_mm)
        return
    exported = export_texts(calib, fmt, unit_mm=unit_mm)
    assert exported.dropped == []
    imported = import_texts(fmt, texts_of(exported), unit_mm=unit_mm)
    # mm -> m -> mm and R -> rotation vector -> R (mrcal) or R2^T R1 (ROS) round to the last bits, not beyond.
    assert_same(imported.calib, calib, rtol=0 if (unit_mm == 1.0 and fmt == "kalibr") else 1e-12)
    assert imported.calib.covariance is None and "no covariance" in imported.calib.covariance_note


def test_ros_rectification_comes_back_as_written():
    calib = calibration("rational")
    rect = rectify(calib)
    imported = import_texts("ros", texts_of(export_texts(calib, "ros", rect=rect)))
    for name in ("R1", "R2", "P1", "P2", "Q"):
        np.testing.assert_allclose(getattr(imported.rect, name), getattr(rect, name), rtol=1e-12, atol=1e-12,
                                   err_msg=name)


def test_lossy_export_refits_the_formats_model_and_states_how_far_it_is_off():
    calib = calibration("thin-prism")
    exported = export_texts(calib, "ros", lossy=True)
    assert len(exported.dropped) == 2  # one line per camera
    assert all("s1 s2 s3 s4" in line and "refitted rational_polynomial" in line for line in exported.dropped)
    info = yaml.safe_load(exported.files["left.yaml"])
    assert info["distortion_model"] == "rational_polynomial" and len(info["distortion_coefficients"]["data"]) == 8
    # The stated miss is where the written model puts the rays of the original lens, checked by hand on the grid.
    K_new = np.array(info["camera_matrix"]["data"]).reshape(3, 3)
    d_new = np.array(info["distortion_coefficients"]["data"])
    stated = float(exported.dropped[0].split("up to ")[1].split(" px")[0])
    d = np.zeros(14)
    d[:12] = LENSES["thin-prism"][0]
    width, height = calib.image_size
    u, v = np.meshgrid(np.linspace(0, width - 1, 33), np.linspace(0, height - 1, 33))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = cv2.undistortPoints(pixels.reshape(-1, 1, 2), calib.K1, d, criteria=(3, 100, 1e-14)).reshape(-1, 2)
    points = np.column_stack([rays, np.ones(len(rays))])
    projected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K_new, d_new)
    miss = np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1)
    assert stated == pytest.approx(float(miss.max()), rel=5e-3)  # printed to 3 digits
    # The refit is better than dropping the terms, which is what it is for.
    kept = d.copy()
    kept[8:] = 0
    assert miss.max() < projection_change_px(calib.K1, d, kept, calib.image_size).max()
    assert projection_change_px(calib.K1, d, d, calib.image_size).max() < 1e-6


def test_kalibr_refuses_k3_unless_lossy():
    with pytest.raises(UnrepresentableLens, match=r"k3, which Kalibr camchain cannot hold \(radtan: k1 k2 p1 p2\)"):
        export_texts(calibration("opencv5"), "kalibr")
    exported = export_texts(calibration("opencv5"), "kalibr", lossy=True)
    assert len(exported.dropped) == 2 and "dropped: left camera: lens model opencv5 has k3" in exported.dropped[0]


# ------------------------------------------------------------------ what each project's own reader expects


def test_ros_files_have_the_layout_camera_calibration_parsers_reads():
    """parse_yml.cpp: image_width/height, camera_name, camera_matrix/rectification_matrix/projection_matrix as
    {rows, cols, data} of 3x3/3x3/3x4 (asserted), distortion_model, distortion_coefficients rows x cols values."""
    calib = calibration("opencv5")
    exported = export_texts(calib, "ros")
    assert set(exported.files) == {"left.yaml", "right.yaml"}
    for name, text in exported.files.items():
        info = yaml.safe_load(text)
        assert info["camera_name"] == name.split(".")[0]
        assert set(info) == {"image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                             "distortion_coefficients", "rectification_matrix", "projection_matrix"}
        assert (info["image_width"], info["image_height"]) == (1920, 1080)
        for key, shape in (("camera_matrix", (3, 3)), ("rectification_matrix", (3, 3)), ("projection_matrix", (3, 4)),
                           ("distortion_coefficients", (1, 5))):
            assert (info[key]["rows"], info[key]["cols"]) == shape and len(info[key]["data"]) == shape[0] * shape[1]
        assert info["distortion_model"] == "plumb_bob"  # sensor_msgs::distortion_models::PLUMB_BOB
    # sensor_msgs/CameraInfo: the right camera's P[0, 3] = Tx = -fx' * B, B in metres.
    right = yaml.safe_load(exported.files["right.yaml"])["projection_matrix"]["data"]
    rect = rectify(calib)
    baseline_m = np.linalg.norm(rect.R2 @ calib.T) / 1000
    assert right[3] == pytest.approx(-right[0] * baseline_m, rel=1e-12)


def test_kalibr_camchain_passes_kalibrs_checks():
    """ConfigReader.py: cam0/cam1; pinhole intrinsics 4 floats >= 0; radtan 4 coefficients; resolution 2 ints;
    cam1.T_cn_cnm1 a 4x4 transformation taking cam0 (left) coordinates to cam1 (right), in metres."""
    calib = calibration("opencv4")
    chain = yaml.safe_load(export_texts(calib, "kalibr").files["camchain.yaml"])
    assert set(chain) == {"cam0", "cam1"}
    for key in ("cam0", "cam1"):
        cam = chain[key]
        assert cam["camera_model"] == "pinhole" and len(cam["intrinsics"]) == 4
        assert all(isinstance(v, float) and v >= 0 for v in cam["intrinsics"])
        assert cam["distortion_model"] == "radtan" and len(cam["distortion_coeffs"]) == 4
        assert len(cam["resolution"]) == 2 and all(isinstance(v, int) for v in cam["resolution"])
        assert isinstance(cam["rostopic"], str)
    T = np.array(chain["cam1"]["T_cn_cnm1"])
    assert T.shape == (4, 4) and "T_cn_cnm1" not in chain["cam0"]
    X_left = np.array([120.0, -40.0, 900.0])
    np.testing.assert_allclose(T @ [*(X_left / 1000), 1], [*((calib.R @ X_left + calib.T) / 1000), 1], rtol=1e-12)


def test_mrcal_model_has_the_keys_mrcals_reader_requires():
    """cameramodel.py _read_into_self: ast.literal_eval of a dict with lensmodel, intrinsics, extrinsics (6),
    imagersize; LENSMODEL_OPENCV8 intrinsics are fx fy cx cy k1 k2 p1 p2 k3 k4 k5 k6."""
    import ast

    calib = calibration("rational")
    files = export_texts(calib, "mrcal").files
    left, right = (ast.literal_eval(files[f"{side}.cameramodel"]) for side in ("left", "right"))
    assert {"lensmodel", "intrinsics", "extrinsics", "imagersize"} <= set(left)
    assert left["lensmodel"] == "LENSMODEL_OPENCV8" and len(left["intrinsics"]) == 12
    assert left["extrinsics"] == [0.0] * 6 and left["imagersize"] == [1920, 1080]
    np.testing.assert_allclose(right["extrinsics"][:3], cv2.Rodrigues(calib.R)[0].ravel(), rtol=1e-14)
    np.testing.assert_allclose(right["extrinsics"][3:], calib.T / 1000, rtol=1e-14)


MRCAL_CHECK = r"""
import json, sys
import numpy as np
import mrcal
out = {}
for side in ("left", "right"):
    m = mrcal.cameramodel(sys.argv[1] + "/" + side + ".cameramodel")
    lensmodel, intrinsics = m.intrinsics()
    points = np.array([[120.0, -40.0, 900.0], [-300.0, 200.0, 700.0]]) / 1000
    out[side] = {"lensmodel": lensmodel, "intrinsics": intrinsics.tolist(), "rt": m.extrinsics_rt_fromref().tolist(),
                 "projected": mrcal.project(mrcal.transform_point_rt(m.extrinsics_rt_fromref(), points),
                                            lensmodel, intrinsics).tolist()}
print(json.dumps(out))
"""


@pytest.mark.parametrize("lens", ["opencv4", "opencv5", "rational", "thin-prism"])
def test_mrcal_reads_our_models_and_projects_as_opencv_does(tmp_path, lens):
    python = mrcal_python()
    if python is None:
        pytest.skip("mrcal is not installed (apt-get install mrcal python3-mrcal; or STEREO_BENCH_MRCAL_PYTHON)")
    calib = calibration(lens)
    for name, text in export_texts(calib, "mrcal").files.items():
        (tmp_path / name).write_text(text)
    result = json.loads(subprocess.run([python, "-c", MRCAL_CHECK, str(tmp_path)], capture_output=True, text=True,
                                       check=True, timeout=120).stdout)
    points = np.array([[120.0, -40.0, 900.0], [-300.0, 200.0, 700.0]])
    for side, K, D, rvec, tvec in (("left", calib.K1, calib.D1, np.zeros(3), np.zeros(3)),
                                   ("right", calib.K2, calib.D2, cv2.Rodrigues(calib.R)[0], calib.T)):
        expected, _ = cv2.projectPoints(points, rvec, tvec, K, D)
        np.testing.assert_allclose(result[side]["projected"], expected.reshape(-1, 2), atol=1e-6, err_msg=side)


# ------------------------------------------------------------------ bad files


@pytest.mark.parametrize(("fmt", "edit", "expected"), [
    ("ros", lambda t: t.replace("camera_matrix:", "camera_matrx:"), r"left\.yaml: field 'camera_matrix': missing"),
    ("ros", lambda t: t.replace("rows: 3\n  cols: 4", "rows: 3\n  cols: 3"),
     r"left\.yaml: field 'projection_matrix': .*9 values|left\.yaml: field 'projection_matrix'"),
    ("ros", lambda t: t.replace("plumb_bob", "equidistant"), r"left\.yaml: field 'distortion_model': 'equidistant'"),
    ("ros", lambda t: t.replace("image_width: 1920", "image_width: [1920"), r"left\.yaml: not readable YAML"),
    ("kalibr", lambda t: t.replace("  T_cn_cnm1:", "  T_cn_cnm2:"), r"camchain\.yaml: field 'cam1\.T_cn_cnm1'"),
    ("kalibr", lambda t: t.replace("resolution: [1920, 1080]", "resolution: [1920.5, 1080]", 1),
     r"camchain\.yaml: field 'cam0\.resolution\.0'"),
    ("kalibr", lambda t: t.replace("radtan", "equidistant", 1), r"field 'cam0\.distortion_model': 'equidistant'"),
    ("mrcal", lambda t: t.replace("LENSMODEL_OPENCV4", "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=30_Ny=18_fov_x"
                                  "_deg=150"), r"left\.cameramodel: field 'lensmodel': 'LENSMODEL_SPLINED"),
    ("mrcal", lambda t: t.replace("'imagersize'", "'imagersz'"), r"left\.cameramodel: field 'imagersize': missing"),
    ("mrcal", lambda t: t.replace("{", "{{", 1), r"left\.cameramodel: not a readable \.cameramodel"),
])
def test_a_bad_file_is_named_with_its_field(fmt, edit, expected):
    texts = texts_of(export_texts(calibration("opencv4"), fmt, unit_mm=1000.0))
    texts[0] = (texts[0][0], edit(texts[0][1]))
    with pytest.raises(FormatError, match=expected):
        import_texts(fmt, texts)


def test_ros_files_of_single_cameras_are_refused_as_no_stereo_pair():
    texts = texts_of(export_texts(calibration("opencv4"), "ros"))
    info = yaml.safe_load(texts[1][1])
    info["projection_matrix"]["data"][3] = 0.0
    with pytest.raises(FormatError, match=r"right\.yaml: field 'projection_matrix': .* no stereo baseline"):
        import_texts("ros", [texts[0], ("right.yaml", yaml.safe_dump(info))])


@pytest.mark.parametrize("fmt", ["ros", "kalibr", "mrcal"])
def test_millimetre_files_read_as_metres_are_refused_with_the_fix(fmt):
    """Written with --units mm, read with the default metres: |T| 99 600 mm, which no bench holds (the measured square
    came out 1000x too): refused, saying which option reads them."""
    texts = texts_of(export_texts(calibration("opencv4"), fmt, unit_mm=1.0))
    with pytest.raises(FormatError, match=r"baseline \|T\| = 99\d{3} mm read in metres is over 10 m: .*--units mm"):
        import_texts(fmt, texts)
    assert abs(np.linalg.norm(import_texts(fmt, texts, unit_mm=1.0).calib.T) - 99.84) < 0.01


@pytest.mark.parametrize("fmt", ["ros", "mrcal"])
def test_the_two_cameras_files_given_the_other_way_round_are_refused(fmt):
    """The right camera's file first: T_x > 0, the right camera to the left of the left one (this project's rig puts
    it at +x, as calibrate's left_right gate holds), and the intrinsics exchanged: refused, saying so."""
    texts = texts_of(export_texts(calibration("opencv4"), fmt))
    with pytest.raises(FormatError, match=r"the right camera sits 99\.\d mm to the LEFT of the left one: the files "
                                          r"name the cameras the other way round"):
        import_texts(fmt, texts[::-1])


# ------------------------------------------------------------------ the commands


@pytest.fixture(scope="module")
def real_calib(tmp_path_factory):
    out = tmp_path_factory.mktemp("calib")
    assert main(["calibrate", "--board", "9x6", "--square", "30", "--left", str(OPENCV_SAMPLE / "left*.jpg"),
                 "--right", str(OPENCV_SAMPLE / "right*.jpg"), "--out", str(out), "--lens-model", "opencv5"]) == 0
    return out


@pytest.mark.parametrize("fmt", ["ros", "kalibr", "mrcal"])
def test_export_import_then_measure_as_with_the_original(capsys, tmp_path, real_calib, fmt):
    original = read_calibration(real_calib)
    if fmt == "kalibr":  # k3 does not fit radtan: refused in one line, exit status 2, nothing written
        code, _, err = run(capsys, "export", str(real_calib), "--to", fmt, "--out", str(tmp_path / "x"))
        assert code == 2 and len(err.strip().splitlines()) == 1 and "--lossy" in err and "k3" in err
        assert not (tmp_path / "x").exists()
        code, out, _ = run(capsys, "export", str(real_calib), "--to", fmt, "--out", str(tmp_path / "x"), "--lossy")
        assert code == 0 and out.count("dropped: left camera") == 1 and out.count("dropped: right camera") == 1
    else:
        code, out, _ = run(capsys, "export", str(real_calib), "--to", fmt, "--out", str(tmp_path / "x"))
        assert code == 0
    lines = out.splitlines()
    assert any(line.startswith("dropped: covariance") for line in lines)
    assert any(line.startswith("dropped: quality gates") for line in lines)
    files = {"ros": ["left.yaml", "right.yaml"], "kalibr": ["camchain.yaml"],
             "mrcal": ["left.cameramodel", "right.cameramodel"]}[fmt]
    code, out, _ = run(capsys, "import", *(str(tmp_path / "x" / f) for f in files), "--from", fmt, "--out",
                       str(tmp_path / "c"), "--board", "9x6", "--square", "30", "--json")
    assert code == 0, out
    report = json.loads(out)
    imported = read_calibration(tmp_path / "c")
    if fmt != "kalibr":
        assert_same(imported, original)
        assert report["lens_model"] == "opencv5"
    else:
        np.testing.assert_allclose(imported.R, original.R, rtol=1e-12)  # the refit changes the lenses only
        np.testing.assert_allclose(imported.T, original.T, rtol=1e-12)
        assert imported.D1[0, 4] == 0 and report["lens_model"] == "opencv4"
    pair = [str(OPENCV_SAMPLE / "left03.jpg"), str(OPENCV_SAMPLE / "right03.jpg")]
    results = []
    for calib_dir in (real_calib, tmp_path / "c"):
        code, out, _ = run(capsys, "measure", "--calib", str(calib_dir), *pair, "--json")
        assert code == 0
        results.append(json.loads(out))
    assert results[1]["board"]["square_from"].endswith("(recorded)")
    tolerance = 1e-9 if fmt != "kalibr" else 0.005  # kalibr: radtan refitted to the k3 lens (2 px at the corners)
    assert results[1]["error_mm"] == pytest.approx(results[0]["error_mm"], abs=tolerance)


def test_export_of_opencvs_own_sample_files_needs_the_image_size(capsys, tmp_path):
    code, _, err = run(capsys, "export", str(OPENCV_FORMAT), "--to", "ros", "--out", str(tmp_path / "r"))
    assert code == 2 and "image size" in err
    code, out, _ = run(capsys, "export", str(OPENCV_FORMAT), "--to", "ros", "--out", str(tmp_path / "r"),
                       "--image-size", "640x480", "--units", "mm")
    assert code == 0
    info = yaml.safe_load((tmp_path / "r" / "left.yaml").read_text())
    assert info["distortion_model"] == "rational_polynomial"  # the sample fits CALIB_RATIONAL_MODEL
    code, out, _ = run(capsys, "export", str(OPENCV_FORMAT), "--to", "mrcal", "--out", str(tmp_path / "m"),
                       "--image-size", "640x480", "--json")
    report = json.loads(out)
    assert code == 0 and report["format"] == "mrcal" and report["units"] == "m"
    assert report["files"] == [str(tmp_path / "m" / "left.cameramodel"), str(tmp_path / "m" / "right.cameramodel")]
    # The sample's files record no covariance, gates or board: only its rectification is dropped.
    assert [line.split(":")[1].strip() for line in report["dropped"]] == ["rectification R1 R2 P1 P2 Q"]


def test_import_errors_are_one_line_with_exit_status_2(capsys, tmp_path):
    exported = export_texts(calibration("opencv4"), "kalibr")
    bad = tmp_path / "camchain.yaml"
    bad.write_text(exported.files["camchain.yaml"].replace("camera_model: pinhole", "camera_model: omni", 1))
    code, _, err = run(capsys, "import", str(bad), "--from", "kalibr", "--out", str(tmp_path / "c"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{bad}: field 'cam0.camera_model': 'omni' is not supported" in err
    code, _, err = run(capsys, "import", str(bad), "--from", "ros", "--out", str(tmp_path / "c"))
    assert code == 2 and "two camera_info files" in err
    code, _, err = run(capsys, "import", str(tmp_path / "missing.yaml"), "--from", "kalibr", "--out",
                       str(tmp_path / "c"))
    assert code == 2 and "missing.yaml" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "c").exists()


def test_import_refuses_to_overwrite(capsys, tmp_path):
    (tmp_path / "c").mkdir()
    write_calibration(tmp_path / "c", calibration("opencv4"))
    (tmp_path / "k.yaml").write_text(export_texts(calibration("opencv4"), "kalibr").files["camchain.yaml"])
    code, _, err = run(capsys, "import", str(tmp_path / "k.yaml"), "--from", "kalibr", "--out", str(tmp_path / "c"))
    assert code == 2 and "exists" in err and "--force" in err


def test_the_commands_formats_are_the_codecs():
    from stereo_bench.cli.formats import FORMATS as CLI_FORMATS
    from stereo_bench.vision.formats import FORMATS

    assert CLI_FORMATS == FORMATS


MRCAL_WRITE = r"""
import sys
import numpy as np
import mrcal
left = mrcal.cameramodel(intrinsics=("LENSMODEL_OPENCV8", np.array([float(v) for v in sys.argv[2].split(",")])),
                         imagersize=(1920, 1080))
rt = np.array([float(v) for v in sys.argv[4].split(",")])
right = mrcal.cameramodel(intrinsics=("LENSMODEL_OPENCV8", np.array([float(v) for v in sys.argv[3].split(",")])),
                          imagersize=(1920, 1080), extrinsics_rt_fromref=rt)
left.write(sys.argv[1] + "/left.cameramodel")
right.write(sys.argv[1] + "/right.cameramodel")
"""


def test_models_mrcal_itself_writes_import(tmp_path):
    python = mrcal_python()
    if python is None:
        pytest.skip("mrcal is not installed (apt-get install mrcal python3-mrcal; or STEREO_BENCH_MRCAL_PYTHON)")
    calib = calibration("rational")
    rt = np.concatenate([cv2.Rodrigues(calib.R)[0].ravel(), calib.T / 1000])

    def values(K, D):
        return ",".join(repr(float(v)) for v in [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *np.ravel(D)])

    subprocess.run([python, "-c", MRCAL_WRITE, str(tmp_path), values(calib.K1, calib.D1), values(calib.K2, calib.D2),
                    ",".join(repr(float(v)) for v in rt)], check=True, timeout=120, capture_output=True)
    texts = [(str(tmp_path / f"{side}.cameramodel"), (tmp_path / f"{side}.cameramodel").read_text())
             for side in ("left", "right")]
    imported = import_texts("mrcal", texts)
    assert_same(imported.calib, calib, rtol=1e-8)  # mrcal's writer keeps 10 significant digits


# ------------------------------------------------------------------ files as the other tools write them

ROS_LEFT = """image_width: 640
image_height: 480
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [ 520.5,    0.  , 321.25,
            0.  ,  521.75, 241.5,
            0.  ,    0.  ,   1.  ]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.281, 0.0712, 0.0003, -0.0002, 0.]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1., 0., 0., 0., 1., 0., 0., 0., 1.]
projection_matrix:
  rows: 3
  cols: 4
  data: [500., 0., 320., 0., 0., 500., 240., 0., 0., 0., 1., 0.]
"""


def test_a_stereo_pair_as_ros_camera_calibration_writes_it():
    """Two camera_info files in ROS's own layout (multi-line flow lists, camera_name with a namespace): a parallel
    pair 0.12 m apart, P2[0, 3] = -fx' B = -500 * 0.12."""
    right = (ROS_LEFT.replace("narrow_stereo/left", "narrow_stereo/right")
             .replace("500., 0., 320., 0.,", "500., 0., 320., -60.,"))
    imported = import_texts("ros", [("left.yaml", ROS_LEFT), ("right.yaml", right)])
    np.testing.assert_allclose(imported.calib.T, [-120.0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(imported.calib.R, np.eye(3), atol=1e-15)
    assert imported.calib.K1[1, 1] == 521.75 and imported.calib.lens_model == "opencv4"
    assert imported.rect.Q[3, 2] == pytest.approx(1 / 120.0)  # -1 / Tx, Tx = -120 mm


KALIBR_CAMCHAIN = """cam0:
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.2834, 0.0739, 0.00019, 1.76e-05]
  distortion_model: radtan
  intrinsics: [458.65, 457.3, 367.2, 248.4]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, -0.11]
  - [0.0, 1.0, 0.0, 0.0004]
  - [0.0, 0.0, 1.0, -0.0009]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.2836, 0.0745, -0.0001, -3.5e-05]
  distortion_model: radtan
  intrinsics: [457.59, 456.13, 379.9, 255.2]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
"""


def test_a_camchain_as_kalibr_writes_it():
    """Kalibr's yaml.dump layout (keys sorted, block lists of flow rows), metres."""
    imported = import_texts("kalibr", [("camchain-stereo.yaml", KALIBR_CAMCHAIN)])
    np.testing.assert_allclose(imported.calib.T, [-110.0, 0.4, -0.9], rtol=1e-12)
    assert imported.calib.image_size == (752, 480)
    np.testing.assert_array_equal(imported.calib.D2, [[-0.2836, 0.0745, -0.0001, -3.5e-05, 0.0]])


def test_an_imported_calibration_serves_as_given_intrinsics(capsys, tmp_path, real_calib):
    """calibrate --intrinsics with a directory imported from ROS: the fixed-mode fit of the same views."""
    assert main(["export", str(real_calib), "--to", "ros", "--out", str(tmp_path / "ros")]) == 0
    assert main(["import", str(tmp_path / "ros" / "left.yaml"), str(tmp_path / "ros" / "right.yaml"), "--from", "ros",
                 "--out", str(tmp_path / "c")]) == 0
    capsys.readouterr()
    code, out, _ = run(capsys, "calibrate", "--board", "9x6", "--square", "30", "--intrinsics", str(tmp_path / "c"),
                       "--left", str(OPENCV_SAMPLE / "left*.jpg"), "--right", str(OPENCV_SAMPLE / "right*.jpg"),
                       "--out", str(tmp_path / "fixed"), "--json")
    report = json.loads(out)
    assert code == 0 and report["mode"] == "fixed"
    assert report["left"]["fx"] == pytest.approx(read_calibration(real_calib).K1[0, 0], rel=1e-12)
    assert report["baseline_mm"] == pytest.approx(read_calibration(real_calib).baseline_mm, abs=0.05)
    assert report["uncertainty"] is None  # the imported intrinsics carry no covariance: unknown, not zero


def test_a_campaign_row_measured_with_a_calibration_without_rms_prints():
    """A fixed-mode campaign on an imported calib_dir (no RMS recorded: the store has none) printed its row with a
    KeyError; a full run with one measured 27.0022 mm as with the directory it was exported from (docs/FORMATS.md)."""
    from stereo_bench.cli.progress import format_row as _format_row

    row = {"config_id": "B100_Z500_A90", "baseline_mm": 100.0, "distance_mm": 500.0, "alpha_deg": 90.0,
           "status": "measured", "square_mean_mm": 27.0022, "error_mm": 0.0022, "U_expanded_mm": 0.0316,
           "n_squares": 279}
    assert _format_row(row).endswith("(n 279, RMS not recorded)")
    assert _format_row({**row, "rms_px": float("nan")}).endswith("(n 279, RMS not recorded)")
    assert _format_row({**row, "rms_px": 0.25}).endswith("(n 279, RMS 0.250 px)")
