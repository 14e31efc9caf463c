"""Intrinsics files as real tools write them (K.json, cv2.FileStorage YAML / XML / JSON, ARKit, Record3D), made on
the fly, every refusal, and lens distortion removed from a photo and its depth."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from footmesh.formats.camera import CameraFile, parse_camera_file, undistort
from footmesh.load import Intrinsics, LoadError

W, H = 160, 120  # the photo, px
FX, FY, CX, CY = 150.0, 152.0, 79.5, 59.5
K = np.array([[FX, 0.0, CX], [0.0, FY, CY], [0.0, 0.0, 1.0]])
D = np.array([-0.15, 0.04, 0.001, -0.0015, 0.0])  # barrel, like a phone's main camera before correction
GOOD_K = {"fx": FX, "fy": FY, "cx": CX, "cy": CY, "width": W, "height": H}


def filestorage(path: Path, **nodes: object) -> Path:
    """``path`` written by cv2.FileStorage (YAML, XML or JSON by its extension), as calibration tools do."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in nodes.items():
        if isinstance(value, list):  # a cv::Size or a plain sequence
            fs.startWriteStruct(key, cv2.FileNode_SEQ | cv2.FileNode_FLOW)
            for item in value:
                fs.write("", item)
            fs.endWriteStruct()
        else:
            fs.write(key, value)
    fs.release()
    return path


def write_json(path: Path, obj: object) -> Path:
    path.write_text(json.dumps(obj))
    return path


def read(path: Path, size: tuple[int, int] = (W, H), rotated: bool = False) -> CameraFile:
    return parse_camera_file(path.read_bytes(), path, size, rotated)


def refusal(path: Path, size: tuple[int, int] = (W, H), rotated: bool = False) -> str:
    """The LoadError message for ``path``: one line, starting with the file's name."""
    with pytest.raises(LoadError) as exc:
        read(path, size, rotated)
    message = str(exc.value)
    assert "\n" not in message and message.startswith(f"intrinsics file {path}")
    return message


def same_camera(k: Intrinsics, fx: float = FX, fy: float = FY, cx: float = CX, cy: float = CY) -> bool:
    return np.allclose([k.fx, k.fy, k.cx, k.cy], [fx, fy, cx, cy]) and k.size == (W, H) and k.source == "file"


# --- K.json ---------------------------------------------------------------------------------------------------


def test_k_json_with_unknown_keys_is_read_and_the_keys_are_named_in_a_note(tmp_path):
    path = write_json(tmp_path / "K.json", {**GOOD_K, "serial": "A1", "depth_unit_mm": 1})
    camera = read(path)
    assert same_camera(camera.intrinsics) and camera.kind == "K.json" and camera.distortion is None
    assert camera.notes == ("ignored keys 'depth_unit_mm', 'serial' in K.json",)
    assert "K.json" in camera.intrinsics.note
    assert read(write_json(tmp_path / "plain.json", GOOD_K)).notes == ()


@pytest.mark.parametrize("key", ["dist", "distortion", "distortion_coefficients"])
@pytest.mark.parametrize("count", [4, 5, 8, 12, 14])
def test_k_json_distortion_lists_of_every_opencv_length(tmp_path, key, count):
    coeffs = np.zeros(count)
    coeffs[:4] = D[:4]
    camera = read(write_json(tmp_path / "K.json", {**GOOD_K, key: coeffs.tolist()}))
    np.testing.assert_array_equal(camera.distortion, coeffs)
    assert camera.notes == ()


def test_k_json_named_coefficients_fill_the_shortest_opencv_model(tmp_path):
    camera = read(write_json(tmp_path / "K.json", {**GOOD_K, "k1": -0.1, "p2": 0.002}))
    np.testing.assert_array_equal(camera.distortion, [-0.1, 0.0, 0.0, 0.002, 0.0])
    rational = read(write_json(tmp_path / "R.json", {**GOOD_K, "k1": -0.1, "k4": 0.05}))
    np.testing.assert_array_equal(rational.distortion, [-0.1, 0, 0, 0, 0, 0.05, 0, 0])


def test_all_zero_distortion_is_no_distortion(tmp_path):
    assert read(write_json(tmp_path / "K.json", {**GOOD_K, "dist": [0, 0, 0, 0, 0]})).distortion is None


# --- OpenCV calibration files ---------------------------------------------------------------------------------


@pytest.mark.parametrize("ext", ["yml", "xml", "json"])
def test_opencv_calibration_sample_output_is_read_back(tmp_path, ext):
    """What OpenCV's camera_calibration sample writes, in each syntax cv2.FileStorage has."""
    path = filestorage(
        tmp_path / f"out_camera_data.{ext}",
        calibration_time="Mon Jan  1 10:00:00 2024",
        nr_of_frames=25,
        image_width=W,
        image_height=H,
        board_width=9,
        board_height=6,
        square_size=25.0,
        flags=0,
        fisheye_model=0,
        camera_matrix=K,
        distortion_coefficients=D.reshape(5, 1),
        avg_reprojection_error=0.21,
    )
    camera = read(path)
    assert same_camera(camera.intrinsics) and camera.kind == "OpenCV calibration"
    np.testing.assert_array_equal(camera.distortion, D)
    assert camera.notes == (
        "ignored keys 'avg_reprojection_error', 'board_height', 'board_width', 'calibration_time', 'flags', "
        "'nr_of_frames', 'square_size' in OpenCV calibration",
    )


@pytest.mark.parametrize("header", ["%YAML:1.0\n---\n", "%YAML 1.2\n---\n", ""])
def test_opencv_yaml_of_every_header_and_ros_camera_info(tmp_path, header):
    """OpenCV 3 / 4 write ``%YAML:1.0``, OpenCV 5 ``%YAML 1.2``; ROS camera_info YAML has none and no ``dt``."""
    opencv = filestorage(tmp_path / "c.yml", image_width=W, image_height=H, camera_matrix=K, D=D.reshape(1, 5))
    body = opencv.read_text().split("---\n", 1)[1]
    (tmp_path / "h.yml").write_text(header + body)
    assert same_camera(read(tmp_path / "h.yml").intrinsics)
    ros = (
        f"{header}image_width: {W}\nimage_height: {H}\ncamera_name: narrow_stereo\ncamera_matrix:\n  rows: 3\n"
        f"  cols: 3\n  data: [{FX}, 0, {CX}, 0, {FY}, {CY}, 0, 0, 1]\ndistortion_model: plumb_bob\n"
        f"distortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [{', '.join(map(str, D))}]\n"
    )
    (tmp_path / "ros.yaml").write_text(ros)
    camera = read(tmp_path / "ros.yaml")
    assert same_camera(camera.intrinsics) and camera.notes == ("ignored key 'camera_name' in OpenCV calibration",)
    np.testing.assert_array_equal(camera.distortion, D)


@pytest.mark.parametrize(
    ("matrix_key", "dist_key", "size"),
    [
        ("cameraMatrix", "distCoeffs", {"imageSize": [W, H]}),
        ("K", "D", {"image_size": [W, H]}),
        ("intrinsic_matrix", "dist_coeffs", {"image_width": W, "image_height": H}),
    ],
)
@pytest.mark.parametrize("ext", ["yml", "xml"])
def test_opencv_key_aliases(tmp_path, matrix_key, dist_key, size, ext):
    path = filestorage(tmp_path / f"c.{ext}", **size, **{matrix_key: K, dist_key: D.reshape(1, 5)})
    camera = read(path)
    assert same_camera(camera.intrinsics) and camera.kind == "OpenCV calibration" and camera.notes == ()
    np.testing.assert_array_equal(camera.distortion, D)


def test_opencv_json_with_plain_lists(tmp_path):
    """json.dump of ``K.tolist()`` and ``D.tolist()`` (a 1 x 5 list of lists), or OpenCV's rows/cols/data."""
    nested = write_json(
        tmp_path / "a.json", {"camera_matrix": K.tolist(), "dist_coeffs": [D.tolist()], "image_size": [W, H]}
    )
    opencv = {"rows": 3, "cols": 3, "data": K.ravel().tolist()}
    mapped = write_json(tmp_path / "b.json", {"camera_matrix": opencv, "image_width": W, "image_height": H})
    for path in (nested, mapped):
        assert same_camera(read(path).intrinsics) and read(path).kind == "OpenCV calibration"
    np.testing.assert_array_equal(read(nested).distortion, D)


def test_file_without_image_size_is_for_this_photo_only_if_centred(tmp_path):
    camera = read(filestorage(tmp_path / "c.yml", camera_matrix=K))
    assert same_camera(camera.intrinsics)
    assert camera.notes == (
        "no image size in c.yml: taken to be this photo's 160 x 120 px (principal point near its centre)",
    )
    off = K.copy()
    off[0, 2] = 40.0  # 40 px from the centre of a 160 px wide photo: 25 %
    message = refusal(filestorage(tmp_path / "off.yml", camera_matrix=off))
    assert "gives no image size and its principal point (40, 59.5) px is not near the centre" in message


def test_a_skew_within_one_percent_of_fx_is_dropped_with_a_note(tmp_path):
    m = K.copy()
    m[0, 1] = 0.5
    camera = read(write_json(tmp_path / "c.json", {"camera_matrix": m.tolist(), "image_size": [W, H]}))
    assert same_camera(camera.intrinsics) and camera.notes == (
        "skew of 0.5 px in 'camera_matrix' ignored (under 1% of fx)",
    )


# --- ARKit, Record3D ------------------------------------------------------------------------------------------


def test_arkit_row_and_column_major_and_record3d_flat_k_give_the_same_camera(tmp_path):
    row = [[FX, 0, CX], [0, FY, CY], [0, 0, 1]]
    files = {
        "row.json": ({"intrinsics": row, "imageResolution": {"width": W, "height": H}}, "ARKit intrinsics"),
        "col.json": ({"intrinsics": np.array(row).T.tolist(), "imageResolution": [W, H]}, "ARKit intrinsics"),
        "flat.json": ({"intrinsics": np.ravel(row).tolist(), "width": W, "height": H}, "ARKit intrinsics"),
        "metadata": (
            {"K": np.ravel(np.transpose(row)).tolist(), "w": W, "h": H, "dw": 256, "dh": 192},
            "Record3D metadata",
        ),
    }
    for name, (obj, kind) in files.items():
        camera = read(write_json(tmp_path / name, obj))
        assert same_camera(camera.intrinsics) and camera.kind == kind and camera.distortion is None, name
        assert any("column-major" in note for note in camera.notes) == (name in ("col.json", "metadata")), name
    assert read(tmp_path / "metadata").notes[0] == "ignored keys 'dh', 'dw' in Record3D metadata"


def test_arkit_capture_resolution_is_scaled_to_the_photo(tmp_path):
    capture = Intrinsics(1440.0, 1440.0, 959.5, 719.5, 1920, 1440)
    obj = {"intrinsics": capture.matrix().T.tolist(), "imageResolution": {"width": 1920, "height": 1440}}
    camera = read(write_json(tmp_path / "frame.json", obj))
    expected = capture.resized(W, H)
    assert same_camera(camera.intrinsics, expected.fx, expected.fy, expected.cx, expected.cy)
    assert "frame.json is for 1920 x 1440 px, the same aspect ratio as this 160 x 120 px photo" in camera.notes[-1]
    assert "scaled from 1920 x 1440 px" in camera.intrinsics.note


def test_landscape_arkit_intrinsics_for_a_portrait_photo_are_refused_with_the_reason(tmp_path):
    obj = {"intrinsics": K.T.tolist(), "imageResolution": [W, H]}
    path = write_json(tmp_path / "frame.json", obj)
    assert "before the image's EXIF rotation" in refusal(path, (H * 10, W * 10), rotated=True)
    assert "look swapped" in refusal(path, (H * 10, W * 10))
    assert "their aspect ratios differ" in refusal(path, (W, W))


# --- refusals -------------------------------------------------------------------------------------------------


def k_json(**changes: object) -> bytes:
    """A K.json with keys changed, added, or (None) left out."""
    return json.dumps({k: v for k, v in {**GOOD_K, **changes}.items() if v is not None}).encode()


def matrix_json(matrix: object = None, **more: object) -> bytes:
    return json.dumps(
        {"camera_matrix": K.tolist() if matrix is None else matrix, "image_size": [W, H], **more}
    ).encode()


def opencv_yaml(**nodes: object) -> bytes:
    fs = cv2.FileStorage("c.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    for key, value in {"image_width": W, "image_height": H, "camera_matrix": K, **nodes}.items():
        fs.write(key, value)
    return fs.releaseAndGetString().encode()


def with_k(**cells: float) -> list[list[float]]:
    """K as nested rows with some cells changed: ``r1c0=3`` sets row 1, column 0."""
    m = K.copy()
    for cell, value in cells.items():
        m[int(cell[1]), int(cell[3])] = value
    return m.tolist()


REFUSALS = [
    (b"\xff\xd8\xff\xe0\x00\x10JFIF", "is not UTF-8 text"),
    (b" \n\t", "is empty"),
    (b"fx: 1\x00fy: 2", "holds NUL characters"),
    (b"focal length 800 px\n", "is not a JSON, YAML or XML calibration file (OpenCV's YAML parser:"),
    (b"<camera><fx>1</camera>", "is not a JSON, YAML or XML calibration file (OpenCV's XML parser:"),
    (b"a: " + b"[" * 2000 + b"1" + b"]" * 2000, "Too many nested collections"),
    (b"- 1\n- 2\n", "must hold a YAML mapping of keys"),
    (b"[" * 60000, "is not valid JSON: nested too deeply"),
    (b"[[150, 0, 79.5], [0, 152, 59.5], [0, 0, 1]]", "must hold a JSON object"),
    (k_json(fy=None), "missing fy"),
    (k_json(fx="150"), "'fx' must be a number, got \"150\""),
    (k_json(cx=200.0), "cx = 200.0 px is outside the image"),
    (k_json(width=320, height=240), "same aspect ratio, so scale fx, fy, cx, cy by 0.5"),
    (k_json(fx=2.0, fy=2.0), "degree field of view; they must be in pixels, not millimetres"),
    (k_json(dist=[0.1, 0.0], k1=0.1), "gives distortion both as 'dist' and as k1"),
    (k_json(k1=5000.0), "lens distortion has k1 = 5000, beyond the 1000 of any real lens"),
    (k_json(camera_matrix=K.tolist()), "gives both fx, fy, cx, cy and a camera matrix 'camera_matrix'"),
    (opencv_yaml(camera_matrix=K[:2]), "'camera_matrix' is 2 x 3; a camera matrix is 3 x 3"),
    (opencv_yaml(camera_matrix=K.T.copy()), "cx, cy sit in its bottom row; it looks transposed"),
    (opencv_yaml(fisheye_model=1), "is a fisheye calibration (fisheye_model = 1)"),
    (opencv_yaml(distortion_model="equidistant"), "uses distortion model 'equidistant'"),
    (opencv_yaml(distortion_coefficients=np.zeros((1, 6))), "has 6 distortion coefficients; OpenCV's models have 4, 5"),
    (
        opencv_yaml(distortion_coefficients=np.zeros((2, 5))),
        "'distortion_coefficients' is 2 x 5; distortion is one row",
    ),
    (opencv_yaml(D=np.array([50.0, 0, 0, 0, 0])), "lens distortion k1 = 50 moves points to 23 times their distance"),
    (opencv_yaml(D=np.array([-30.0, 0, 0, 0])), "lens distortion k1 = -30 folds the image over"),
    (opencv_yaml(D=np.array([0.1, 0, 0, 0, 1e6])), "has k3 = 1e+06, beyond the 1000 of any real lens"),
    (opencv_yaml(image_width=200), "is for a 200 x 120 px image but the image is 160 x 120 px: their aspect ratios"),
    (matrix_json(image_width=W, image_height=H, image_size=[W, 100]), "gives two image sizes, 160 x 120 px and"),
    (opencv_yaml(camera_matrix=np.array(with_k(r0c0=5.0, r1c1=5.0))), "not millimetres"),
    (matrix_json(with_k(r1c0=3)), "not a pinhole camera matrix: element [1][0] = 3 must be 0"),
    (matrix_json(with_k(r2c2=2)), "element [2][2] = 2 must be 1"),
    (matrix_json(with_k(r0c1=5)), "has a skew of 5 px at [0][1], more than 1% of fx = 150"),
    (matrix_json(with_k(r0c0=-150)), "gives fx = -150; it must be positive"),
    (matrix_json(with_k(r0c2=200)), "cx = 200 px is outside the 160 x 120 px image"),
    (matrix_json([1, 2, 3, 4, 5, 6]), "'camera_matrix' has 6 numbers; a camera matrix has 9"),
    (matrix_json([[150, 0, 79.5], [0, 152], [0, 0, 1]]), "has rows of different lengths"),
    (matrix_json({"rows": 3, "cols": 3, "data": [1] * 8}), "has 8 numbers in data but rows x cols = 3 x 3"),
    (matrix_json({"data": [1] * 9}), "'camera_matrix' lacks rows, cols"),
    (matrix_json("K"), "'camera_matrix' must be a matrix"),
    (matrix_json(K=np.eye(3).tolist()), "gives 'camera_matrix' and 'K' with different values"),
    (matrix_json(image_size=[W]), "'image_size' must be [width, height]"),
    (matrix_json(image_size=[W + 0.5, H]), "'image_size[0]' must be a positive whole number of pixels"),
    (json.dumps({"intrinsics": K.tolist(), "w": W}).encode(), "gives the image size's 'w' but not its height"),
    (b'{"intrinsics": [[NaN, 0, 79.5], [0, 152, 59.5], [0, 0, 1]], "w": 160, "h": 120}', "must be finite"),
    (opencv_yaml().replace(b"150.", b"x"), "'camera_matrix.data[0]' must be a number, got \"x\""),
]


@pytest.mark.parametrize(("data", "expected"), REFUSALS, ids=[expected for _, expected in REFUSALS])
def test_refusals_name_the_file_and_the_problem(tmp_path, data, expected):
    path = tmp_path / "calibration"
    path.write_bytes(data)
    assert expected in refusal(path)


def test_mutated_opencv_files_are_read_or_refused_with_a_load_error(tmp_path):
    rng = np.random.default_rng(5)
    originals = [
        filestorage(
            tmp_path / f"c.{ext}", image_width=W, image_height=H, camera_matrix=K, distortion_coefficients=D
        ).read_bytes()
        for ext in ("yml", "xml")
    ]
    for i in range(400):
        data = bytearray(originals[i % 2])
        for _ in range(rng.integers(1, 5)):
            at = int(rng.integers(0, len(data)))
            if rng.random() < 0.5:
                data[at] = int(rng.integers(32, 127))
            else:
                del data[at : at + int(rng.integers(1, 12))]
        try:
            parse_camera_file(bytes(data), tmp_path / "m.yml", (W, H))
        except LoadError as exc:
            assert "\n" not in str(exc) and str(tmp_path / "m.yml") in str(exc)


# --- undistortion ---------------------------------------------------------------------------------------------

DOTS = [(x, y) for x in range(12, W - 8, 16) for y in range(12, H - 8, 16)]
"""Centres of the grid of dots in the undistorted photo, px."""


def dot_grid() -> np.ndarray:
    """(H, W, 3) uint8: Gaussian dots at ``DOTS`` on black, each one a corner of the grid to find again."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    img = sum(np.exp(-((u - x) ** 2 + (v - y) ** 2) / (2 * 1.6**2)) for x, y in DOTS)
    return np.repeat((255 * np.clip(img, 0, 1)).astype(np.uint8)[..., None], 3, axis=2)


def distorted(image: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """What a lens with ``dist`` records of the scene ``image`` shows: each recorded pixel looks at its ideal point."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    recorded = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4
        ideal = cv2.undistortPointsIter(recorded, K, dist, None, K, criteria)
    else:  # OpenCV 5 took the criteria into undistortPoints
        ideal = cv2.undistortPoints(recorded, K, dist, R=None, P=K, criteria=criteria)
    ideal = ideal.reshape(H, W, 2).astype(np.float32)
    return cv2.remap(image, ideal[..., 0], ideal[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def centroids(image: np.ndarray) -> np.ndarray:
    """(len(DOTS), 2) intensity-weighted centres of the dots near each of ``DOTS`` (searched within 7 px)."""
    grey = image[..., 0].astype(np.float64)
    out = []
    for x, y in DOTS:
        window = grey[y - 7 : y + 8, x - 7 : x + 8]
        v, u = np.mgrid[y - 7 : y + 8, x - 7 : x + 8]
        out.append(((u * window).sum() / window.sum(), (v * window).sum() / window.sum()))
    return np.array(out)


def camera_with(dist: np.ndarray | None) -> CameraFile:
    return CameraFile(Intrinsics(FX, FY, CX, CY, W, H), dist, "K.json", ())


def test_undistort_puts_the_grid_back_where_the_undistorted_photo_has_it(tmp_path):
    scene = dot_grid()
    photo = distorted(scene, D)
    k_file = write_json(tmp_path / "K.json", {**GOOD_K, "dist": D.tolist()})
    fixed, depth = undistort(photo, None, read(k_file))
    truth = centroids(scene)
    assert np.abs(centroids(photo) - truth).max() > 2.0  # the lens does move the corners of the grid
    assert np.abs(centroids(fixed) - truth).max() < 0.5 and depth is None
    assert fixed.shape == photo.shape and fixed.dtype == np.uint8


def test_undistorted_depth_holds_only_measured_values_and_zero_where_nothing_was_seen():
    depth = np.full((H, W), 900.0, np.float32)  # floor
    depth[30:90, 40:120] = 400.0  # a foot, its edge a step of 50 cm
    depth[50:70, 70:90] = 0.0  # a hole the sensor missed
    pincushion = np.array([0.2, 0.0, 0.0, 0.0, 0.0])  # the photo's corners look beyond the recorded frame
    photo, out = undistort(dot_grid(), depth, camera_with(pincushion))
    assert out is not None and out.dtype == np.float32 and out.shape == (H, W) and photo.shape == (H, W, 3)
    assert set(np.unique(out)) <= {0.0, 400.0, 900.0}  # nothing between foreground and floor
    assert out[0, 0] == 0.0 and out[H // 2, 10] == 900.0 and not np.array_equal(out, depth)


def test_no_distortion_returns_the_inputs_themselves():
    rgb, depth = dot_grid(), np.ones((H, W), np.float32)
    for dist in (None, np.zeros(5)):
        out_rgb, out_depth = undistort(rgb, depth, camera_with(dist))
        assert out_rgb is rgb and out_depth is depth
