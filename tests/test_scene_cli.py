"""``harness scene-video`` on a saved motion (the --class path needs the performer, not tested here)."""

import cv2
from harness.motion.simple_walk import walk_motion

from harness.cli import main


def test_scene_video_writes_frames_with_flow_arrows(body, tmp_path, capsys):
    walk_motion(body, 8).save(tmp_path / "walk.npz")
    code = main(["scene-video", "--motion", str(tmp_path / "walk.npz"), "--preset", "low_wall", "--amount", "0.3",
                 "--out", str(tmp_path / "v.gif"), "--png", str(tmp_path / "f.png"), "--frame", "5"])
    assert code == 0
    assert (tmp_path / "v.gif").stat().st_size > 0
    img = cv2.imread(str(tmp_path / "f.png"))
    assert img.shape == (480, 640, 3)
    # Yellow arrows (BGR 0, 230, 255) are drawn.
    yellow = (img[..., 2] > 200) & (img[..., 1] > 180) & (img[..., 0] < 80)
    assert yellow.sum() > 50
    assert "obstacle occlusion 0.3" in capsys.readouterr().out


def test_scene_video_bad_preset_is_one_line_error(body, tmp_path, capsys):
    walk_motion(body, 4).save(tmp_path / "walk.npz")
    code = main(["scene-video", "--motion", str(tmp_path / "walk.npz"), "--preset", "fence", "--amount", "0.2",
                 "--out", str(tmp_path / "v.gif")])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "fence" in err and "\n" not in err
    assert not (tmp_path / "v.gif").exists()
