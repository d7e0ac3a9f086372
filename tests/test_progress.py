"""Progress: a live bar on a terminal, a line at most every 30 s in a log."""

import io

from harness.evaluation import runner
from harness.evaluation.loading import parse_scenario
from harness.evaluation.progress import LOG_INTERVAL_S, LogProgress, progress

from fakes import TINY, fake_run  # noqa: E402


class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_log_gets_a_line_at_most_every_30_s_and_one_at_the_end():
    """480 runs, one finished every second (8 minutes): at most one line per 30 s, and the last one says
    all runs finished."""
    clock, out = _Clock(), io.StringIO()
    bar = LogProgress(480, "default", out, clock)
    times = []
    for _ in range(480):
        clock.t += 1.0
        before = out.getvalue().count("\n")
        bar.update(1)
        if out.getvalue().count("\n") > before:
            times.append(clock.t)
    bar.close()
    lines = out.getvalue().splitlines()
    assert LOG_INTERVAL_S == 30.0
    assert len(lines) == len(times) + 1 <= 480 / 30 + 1
    assert all(b - a >= 30.0 for a, b in zip(times, times[1:]))
    assert times[0] - 1000.0 >= 30.0
    assert lines[0] == "default: 30/480 runs, 30 s, about 7 min 30 s left"
    assert lines[-1] == "default: 480/480 runs, 8 min 0 s"
    assert len(out.getvalue()) < 1500


def test_a_terminal_keeps_the_live_bar_and_quiet_shows_nothing():
    from tqdm import tqdm

    terminal = _Terminal()
    bar = progress(3, "ci", stream=terminal)
    assert isinstance(bar, tqdm)
    bar.update(1)
    bar.close()
    assert "\r" in terminal.getvalue()
    log = io.StringIO()
    assert isinstance(progress(3, "ci", stream=log), LogProgress)
    silent = progress(3, "ci", enabled=False, stream=log)
    silent.update(3)
    silent.close()
    assert log.getvalue() == ""


def test_an_evaluation_logged_to_a_file_writes_no_redraws(tmp_path, capsys):
    """The runner's progress into a captured (not a terminal) standard error: no carriage returns, and with
    every run finishing well within the interval (24 runs of a stand-in), only the closing line."""
    runner.run_scenario(parse_scenario(TINY, "tiny.yaml"), tmp_path / "t", fake_run, progress=True)
    err = capsys.readouterr().err
    assert "\r" not in err
    assert len(err.splitlines()) == 1 and err.startswith("tiny: 24/24 runs, ")
