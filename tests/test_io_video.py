import os

import numpy as np
import pytest

from harness.io import save_npz_atomic, write_atomic
from harness.video import VideoError, render_motion, write_video


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.bin"

    def boom(fh):
        fh.write(b"partial")
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        write_atomic(target, boom)
    assert not target.exists() and os.listdir(tmp_path) == []
    save_npz_atomic(target.with_suffix(".npz"), {"a": np.arange(3)})
    assert np.array_equal(np.load(target.with_suffix(".npz"))["a"], np.arange(3))


def test_render_and_write_video(tmp_path, body):
    qpos = np.tile(body.zero_qpos(), (3, 1))
    frames = list(render_motion(body.model, qpos, width=64, height=48))
    assert len(frames) == 3 and frames[0].shape == (48, 64, 3) and frames[0].dtype == np.uint8
    assert frames[0].std() > 5, "the frame should show something, not a blank image"
    for name in ("v.mp4", "v.gif"):
        assert write_video(tmp_path / name, frames, fps=10) == 3
        assert (tmp_path / name).stat().st_size > 0
    with pytest.raises(VideoError, match="must end in"):
        write_video(tmp_path / "v.avi", frames, fps=10)
