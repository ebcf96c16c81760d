"""One case per kind of bad keypoint input: the error names file, camera, frame and field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cascalib import InputError
from cascalib.formats import read_session, read_tracks, read_tracks_many

COCO_PERSON = [[100 + j, 50 + 10 * j, 0.9] for j in range(17)]
CSV_HEADER = "sync_index,port,frame_index,frame_time,point_id,img_loc_x,img_loc_y,obj_loc_x," \
             "obj_loc_y\n"


def _openpose(tmp: Path, frames: dict[int, object]) -> Path:
    folder = tmp / "camA_json"
    folder.mkdir()
    for k, people in frames.items():
        text = people if isinstance(people, str) else json.dumps({"people": people})
        (folder / f"camA.{k:04d}.json").write_text(text)
    return folder


def _op_person(n=25, conf=0.8):
    return {"pose_keypoints_2d": [v for j in range(n) for v in (100 + j, 200 + 5 * j, conf)]}


def _mmpose(tmp: Path, frames: list[list[dict]]) -> Path:
    path = tmp / "camB.json"
    path.write_text(json.dumps([{"frame_id": k, "instances": inst}
                                for k, inst in enumerate(frames)]))
    return path


def _inst(kps=None, scores=None):
    kps = kps if kps is not None else [[100 + j, 50 + 10 * j] for j in range(17)]
    return {"keypoints": kps, "keypoint_scores": scores or [0.9] * len(kps)}


def _write(tmp: Path, name: str, text: str) -> Path:
    path = tmp / name
    path.write_text(text)
    return path


def _ref(tmp: Path, records: list[dict]) -> Path:
    return _write(tmp, "camC.json", json.dumps({"Info": records}))


# Each case: (build(tmp) -> path, read kwargs, expected file name, camera, frame, field, regex).
CASES = {
    "unparseable json": (
        lambda t: _write(t, "camB.json", '[{"frame_id": 0,\n "instances": [\n  {"keypoints": ]'),
        {}, "camB.json", "camB", None, None, r"not valid JSON: .* line 3, column 17"),
    "unparseable openpose frame": (
        lambda t: _openpose(t, {0: [_op_person()], 1: '{"people": [}'}),
        {}, "camA.0001.json", "camA", None, None, r"not valid JSON.*line 1, column 13"),
    "openpose frame without people": (
        lambda t: _openpose(t, {0: [_op_person()], 1: '{"persons": []}'}),
        {}, "camA.0001.json", "camA", 1, "people", "'people' list"),
    "openpose wrong joint count": (
        lambda t: _openpose(t, {0: [_op_person()], 3: [_op_person(), _op_person(24)]}),
        {}, "camA.0003.json", "camA", 3, "pose_keypoints_2d", "expected 25 joints, got 24"),
    "openpose values not triples": (
        lambda t: _openpose(t, {0: [{"pose_keypoints_2d": [1.0, 2.0, 0.5, 4.0]}]}),
        {}, "camA.0000.json", "camA", 0, "pose_keypoints_2d", "4 values is not a whole"),
    "openpose negative confidence": (
        lambda t: _openpose(t, {0: [_op_person()], 2: [_op_person(conf=-0.1)]}),
        {}, "camA.0002.json", "camA", 2, "pose_keypoints_2d", "negative confidence -0.1"),
    "openpose skeleton contradicts joint count": (
        lambda t: _openpose(t, {0: [_op_person()], 1: [_op_person()]}),
        {"skeleton": "coco17"}, "camA.0000.json", "camA", 0, "pose_keypoints_2d",
        "expected 17 joints, got 25"),
    "mmpose wrong joint count": (
        lambda t: _mmpose(t, [[_inst()], [], [_inst(), _inst([[1, 2]] * 16)]]),
        {}, "camB.json", "camB", 2, "keypoints", "expected 17 joints, got 16"),
    "mmpose score count": (
        lambda t: _mmpose(t, [[_inst()], [{**_inst(), "keypoint_scores": [0.5] * 3}]]),
        {}, "camB.json", "camB", 1, "keypoint_scores", "expected 17 joints, got 3"),
    "mmpose infinite coordinate": (
        lambda t: _write(t, "camB.json", json.dumps(
            [{"frame_id": 4, "instances": [_inst([[1.0, 2.0]] * 16 + [[float("inf"), 3.0]])]}])),
        {}, "camB.json", "camB", 4, "keypoints", "x of joint 16 is inf"),
    "mmpose negative score": (
        lambda t: _mmpose(t, [[_inst()], [_inst(scores=[0.5] * 16 + [-2.0])]]),
        {}, "camB.json", "camB", 1, "keypoint_scores", "negative confidence -2"),
    "mmpose no detections": (
        lambda t: _mmpose(t, [[], [], []]),
        {}, "camB.json", "camB", None, "instances", "no detections"),
    "mmpose bad frame id": (
        lambda t: _write(t, "camB.json", json.dumps([{"frame_id": -3, "instances": []}])),
        {}, "camB.json", "camB", None, "frame_id", "frame_id must be an integer >= 0"),
    "cascalib-ref null coordinate": (
        lambda t: _ref(t, [{"frame": 0, "keypoints": COCO_PERSON},
                           {"frame": 7, "keypoints": COCO_PERSON[:5] + [[None, 3, 0.5]]
                            + COCO_PERSON[6:]}]),
        {}, "camC.json", "camC", 7, "keypoints", "x of joint 5 is nan"),
    "cascalib-ref NaN token": (
        lambda t: _write(t, "camC.json", '{"Info": [{"frame": 2, "keypoints": [[NaN, 1, 1]'
                         + ", [1, 1, 1]" * 16 + "]}]}"),
        {}, "camC.json", "camC", 2, "keypoints", "x of joint 0 is nan"),
    "cascalib-ref non-integer frame": (
        lambda t: _ref(t, [{"frame": 0, "keypoints": COCO_PERSON},
                           {"frame": "12", "keypoints": COCO_PERSON}]),
        {}, "camC.json", "camC", None, "frame", r"frame number must be an integer >= 0, got '12'"),
    "cascalib-ref text in keypoints": (
        lambda t: _ref(t, [{"frame": 5, "keypoints": [["a", 1, 1]] * 17}]),
        {}, "camC.json", "camC", 5, "keypoints", "must be numbers"),
    "coco wrong joint count": (
        lambda t: _write(t, "camD.json", json.dumps(
            [{"image_id": 0, "keypoints": [1, 2, 1] * 17}, {"image_id": 9,
                                                            "keypoints": [1, 2, 1] * 18}])),
        {}, "camD.json", "camD", 9, "keypoints", "expected 17 joints, got 18"),
    "coco empty list": (
        lambda t: _write(t, "camD.json", "[]"),
        {}, "camD.json", None, None, "keypoints", "no detections"),
    "image size contradicts coordinates": (
        lambda t: _ref(t, [{"frame": 0, "keypoints": [[10, 10, 1]] * 17},
                           {"frame": 3, "keypoints": [[10, 10, 1]] * 16 + [[900, 10, 1]]}]),
        {"image_size": "320x240"}, "camC.json", "camC", 3, "image_size",
        "lies far outside the 320x240 image"),
    "mmpose meta image size": (
        lambda t: _write(t, "camB.json", json.dumps({"meta_info": {"image_size": [640, 0]},
                                                     "instance_info": [{"frame_id": 0,
                                                                        "instances": [_inst()]}]})),
        {}, "camB.json", "camB", None, "image_size", "image size must be positive"),
    "mmpose meta fps": (
        lambda t: _write(t, "camB.json", json.dumps({"meta_info": {"fps": "fast"},
                                                     "instance_info": [{"frame_id": 0,
                                                                        "instances": [_inst()]}]})),
        {}, "camB.json", "camB", None, "fps", "frame rate in the file must be a positive"),
    "given fps": (
        lambda t: _ref(t, [{"frame": 0, "keypoints": COCO_PERSON}]),
        {"fps": {"camC": -5}}, None, "camC", None, "fps", "given frame rate must be a positive"),
    "unknown json format": (
        lambda t: _write(t, "camE.json", '{"frames": []}'),
        {}, "camE.json", None, None, "format", r"unknown keypoint format.*\['frames'\]"),
    "unknown text format": (
        lambda t: _write(t, "camE.txt", "frame x y\n1 2 3\n"),
        {}, "camE.txt", None, None, "format", "unknown keypoint format"),
    "unknown format name": (
        lambda t: _write(t, "camE.json", "[]"),
        {"format": "vicon"}, None, None, None, "format", "unknown keypoint format 'vicon'"),
    "unknown skeleton name": (
        lambda t: _ref(t, [{"frame": 0, "keypoints": COCO_PERSON}]),
        {"skeleton": "body99"}, "camC.json", "camC", None, "skeleton", "unknown skeleton"),
    "csv text cell": (
        lambda t: _write(t, "xy.csv", CSV_HEADER + "0,1,0,1.0,0,10,20,,\n0,1,4,1.2,0,abc,20,,\n"),
        {}, "xy.csv", "port_1", 4, "img_loc_x", "line 3: 'abc' is not a number"),
    "csv NaN coordinate": (
        lambda t: _write(t, "xy.csv", CSV_HEADER + "0,2,0,1.0,0,10,20,,\n0,2,6,1.2,3,nan,20,,\n"),
        {}, "xy.csv", "xy", 6, "img_loc_x", "landmark 3 has no finite coordinate"),
    "csv duplicate landmark": (
        lambda t: _write(t, "xy.csv", CSV_HEADER + "0,0,5,1.0,7,10,20,,\n0,0,5,1.0,7,11,20,,\n"),
        {}, "xy.csv", "xy", 5, "point_id", "landmark 7 appears twice"),
    "csv contradicting frame times": (
        lambda t: _write(t, "xy.csv", CSV_HEADER + "0,0,5,1.0,7,10,20,,\n0,0,5,1.1,8,11,20,,\n"),
        {}, "xy.csv", "xy", 5, "frame_time", "disagree on frame_time"),
    "csv timestamps not increasing": (
        lambda t: _write(t, "xy.csv", CSV_HEADER + "0,0,0,2.0,7,10,20,,\n0,0,1,1.0,7,11,20,,\n"),
        {}, "xy.csv", "xy", 1, "timestamps", "timestamps must increase"),
    "csv missing column": (
        lambda t: _write(t, "xy.csv", "port,frame_index,point_id,img_loc_x,img_loc_y\n"),
        {}, "xy.csv", None, None, "frame_time", "missing CSV column"),
    "csv only a header": (
        lambda t: _write(t, "xy.csv", CSV_HEADER),
        {}, "xy.csv", None, None, "point_id", "no detections"),
    "csv only hand landmarks": (
        lambda t: _write(t, "xy.csv", CSV_HEADER + "0,0,0,1.0,101,10,20,,\n"),
        {}, "xy.csv", "xy", None, "point_id", "no detections"),
    "native shape mismatch": (
        lambda t: _write(t, "camF.json", json.dumps(
            {"schema": "cascalib/tracks@1", "camera": "camF", "skeleton": "coco17",
             "shape": [2, 1, 17], "keypoints": [[[[1, 2, 1]] * 17]]})),
        {}, "camF.json", "camF", None, "keypoints", "nested lists of 2 frames x 1 persons x 17"),
    "native future schema": (
        lambda t: _write(t, "camF.json", json.dumps({"schema": "cascalib/tracks@9"})),
        {}, "camF.json", None, None, "schema", "unsupported schema 'cascalib/tracks@9'"),
    "openpose only missing joints": (
        lambda t: _openpose(t, {0: [_op_person(conf=0.0) | {"pose_keypoints_2d": [0] * 75}]}),
        {}, "camA_json", "camA", None, "keypoints", "no detections"),
    "empty openpose folder": (
        lambda t: _openpose(t, {}),
        {}, "camA_json", "camA", None, None, "no OpenPose frame files"),
    "missing path": (
        lambda t: t / "nothing.json",
        {}, "nothing.json", None, None, None, "no such file or folder"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_names_file_camera_frame_and_field(tmp_path, case):
    build, kwargs, file, camera, frame, field, pattern = CASES[case]
    path = build(tmp_path)
    with pytest.raises(InputError, match=pattern) as info:
        read_tracks_many(path, **kwargs)
    err = info.value
    assert (Path(err.file).name if err.file else None) == file
    assert (err.camera, err.frame, err.field) == (camera, frame, field)
    text = str(err)
    for part in (f"file '{err.file}'" if file else None,
                 f"camera '{camera}'" if camera else None,
                 f"frame {frame}" if frame is not None else None,
                 f"field '{field}'" if field else None):
        assert part is None or part in text, (part, text)


def test_read_tracks_on_a_multi_camera_file_says_so(tmp_path):
    path = _write(tmp_path, "xy.csv", CSV_HEADER + "0,0,0,1.0,0,10,20,,\n0,1,0,1.0,0,10,20,,\n")
    with pytest.raises(InputError, match="holds 2 cameras") as info:
        read_tracks(path)
    assert info.value.file == str(path) and info.value.field == "camera"


def test_read_session_rejects_duplicate_camera_names(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a = _ref(tmp_path / "a", [{"frame": 0, "keypoints": COCO_PERSON}])
    b = _ref(tmp_path / "b", [{"frame": 0, "keypoints": COCO_PERSON}])
    with pytest.raises(InputError, match="duplicate camera name") as info:
        read_session([a, b])
    assert info.value.camera == "camC" and str(a) in str(info.value)
    assert [t.camera for t in read_session([a, b], cameras=["left", "right"])] == ["left",
                                                                                  "right"]
