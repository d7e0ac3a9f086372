"""Engine speed: ms per frame and its breakdown per stage, beside a reference engine measured in the same run.

    MUJOCO_GL=egl python benchmarks/engine_speed.py [--reference COMMIT] [--repeats N] [--profile]

10 primitives (6 demos each), each engine's own default number of particles and model points (``--particles``
and ``--points`` set one for both; this engine has 120 evenly spread points since 2026-12-06, the engines
before it 150 drawn at random), 100 markers, one process. The
observations and the database are made once with this checkout and written to a temporary directory (one-sided
for a reference from before the both-handed database, which knows one chain only); the engine
of this checkout tracks them in this process (its stages and the phases of a clip), then this checkout and
``--reference`` (a git commit, checked out into a temporary worktree; default: the engine before issue 22's
speed work) each wait in a subprocess of their own and take the same clips in turns, clip by clip, which goes
first alternating, ``--repeats`` rounds: the machine's speed drifts by more than a small change is worth within
minutes (10-20% within the hour on an AMD Zen 3), and a clip takes a second, so each pair of clips is timed
under the same conditions. Machines differ in speed (it prints the CPU: its generation and vector width move the
time by up to 1.8x), so the ratio of the two engines' times, pooled over the clip pairs with a bootstrap
interval, is the number to compare; the target is 60 frames per second
(16.7 ms per frame) on one core and 2.5 times the reference's speed. This engine's causal loop (the stages of
every frame, what a live camera needs) is timed apart from its offline estimate (the backward pass, for
evaluation), which ``Tracker.run`` also makes. Numba kernels are compiled (and cached) before timing, for both
engines. ``--profile`` runs the clips once more under cProfile and splits the unprofiled time into the numba
kernels (their time under the profiler, which adds little to a long call) and the Python around them (the
rest: the profiler inflates Python's own time several-fold, so its share is not read from the profile).
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import json
import os
import pkgutil
import pstats
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# The environment as the user gave it: importing ``harness`` sets compile settings of its own checkout
# (``harness._full_vector_width``), which each engine's subprocess must choose for itself.
_USER_ENV = dict(os.environ)
# The engine before the speed work of issue 22 (tracks per primitive, both-handed database, 500 particles).
DEFAULT_REFERENCE = "e3ee26d"

_TIMING_SCRIPT = """
import json, sys, time
import numpy as np
from harness.body import BodyModel
from harness.engine import MotionDatabase, Tracker, TrackerConfig
from harness.observation import Observation
db = MotionDatabase.load(sys.argv[1])
sizes = {} if sys.argv[2] == "default" else {"particles": int(sys.argv[2])}
sizes |= {} if sys.argv[3] == "default" else {"model_points": int(sys.argv[3])}
if hasattr(TrackerConfig, "from_dict"):      # settings in sections (since issue 58)
    named = {"particles": "tracks.particles", "model_points": "model.points"}
    config = TrackerConfig.from_dict({named[k]: v for k, v in sizes.items()} | json.loads(sys.argv[4]))
else:
    config = TrackerConfig(**sizes, **json.loads(sys.argv[4]))
tracker = Tracker(db, BodyModel.load(), config, rng=np.random.default_rng(1))
clips = [Observation.load(path) for path in sys.argv[5:]]
tracker.run(clips[0])        # the first clip compiles the kernels
print("ready", flush=True)
for line in sys.stdin:       # one clip index a line: its whole run and causal loop (s) and frames
    obs = clips[int(line)]
    t0 = time.perf_counter()
    est = tracker.run(obs)
    causal = 1e-3 * sum(est.timing.values()) * len(obs) if getattr(est, "timing", None) else None
    print(json.dumps([time.perf_counter() - t0, causal, len(obs)]), flush=True)
"""


class _Engine:
    """An engine checked out in ``tree`` running in a subprocess of its own (``_TIMING_SCRIPT``), with the
    clips loaded and its kernels compiled; ``run(k)`` times clip ``k``."""

    def __init__(self, tree: Path, db_path: Path, obs_paths: list[Path], particles: int | None,
                 points: int | None, settings: dict):
        self.process = subprocess.Popen(
            [sys.executable, "-c", _TIMING_SCRIPT, str(db_path), str(particles or "default"),
             str(points or "default"), json.dumps(settings), *map(str, obs_paths)], cwd=tree,
            env=dict(_USER_ENV, PYTHONPATH=str(tree)), stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        while self._line() != "ready":          # anything the engine prints while loading
            pass

    def _line(self) -> str:
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError(f"the engine's subprocess stopped (exit code {self.process.wait()})")
        return line.strip()

    def run(self, clip: int) -> tuple[float, float, int]:
        """Seconds of the whole run and of the causal loop (the whole run for an engine without per-stage
        timing), and the clip's frames."""
        self.process.stdin.write(f"{clip}\n")
        self.process.stdin.flush()
        line = self._line()
        while not line.startswith("["):         # anything else the engine prints while it runs
            line = self._line()
        whole, causal, frames = json.loads(line)
        return whole, whole if causal is None else causal, frames

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait()


def side_by_side(commit: str, db_path: Path, obs_paths: list[Path], particles: int | None, points: int | None,
                 repeats: int, settings: dict) -> tuple[np.ndarray, np.ndarray]:
    """This checkout's (with engine ``settings``) and ``commit``'s (its defaults) seconds ``(whole run, causal
    loop)`` and frames per clip, ``(repeats, clips, 3)`` each. Both engines wait in subprocesses of their own and
    take the clips in turns, clip by clip, which goes first alternating: the machine's speed drifts by more than
    a small change is worth within minutes, and a clip takes a second."""
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "reference"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), commit], check=True,
                       capture_output=True)
        engines = []
        try:
            engines = [_Engine(ROOT, db_path, obs_paths, particles, points, settings),
                       _Engine(tree, db_path, obs_paths, particles, points, {})]
            times = np.zeros((2, repeats, len(obs_paths) - 1, 3))
            for r in range(repeats):
                for k in range(1, len(obs_paths)):
                    for e in ((0, 1) if (r + k) % 2 else (1, 0)):
                        times[e, r, k - 1] = engines[e].run(k)
        finally:
            for engine in engines:
                engine.close()
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tree)], check=True,
                           capture_output=True)
    return times[0], times[1]


def paired_ratio(mine: np.ndarray, theirs: np.ndarray, rng: np.random.Generator, draws: int = 2000
                 ) -> tuple[float, float, float]:
    """The reference's time over this engine's, pooled over clip pairs ``(n,)`` timed back to back, with a 95%
    bootstrap interval over the pairs."""
    ratio = theirs.sum() / mine.sum()
    pick = rng.integers(0, len(mine), (draws, len(mine)))
    boot = theirs[pick].sum(axis=1) / mine[pick].sum(axis=1)
    return ratio, *np.percentile(boot, [2.5, 97.5])


def print_profile(profiler: cProfile.Profile, frames: int, whole_ms: float) -> None:
    """The unprofiled time per frame ``whole_ms`` split into the engine's numba kernels (each named, their time
    under ``profiler``), MuJoCo's kinematics, and everything else (Python and the numpy calls it makes)."""
    import numba
    import harness.engine as engine
    kernels = {}
    for module in pkgutil.iter_modules(engine.__path__):
        mod = importlib.import_module(f"harness.engine.{module.name}")
        for name, obj in vars(mod).items():
            if isinstance(obj, numba.core.registry.CPUDispatcher):
                code = obj.py_func.__code__
                kernels[(code.co_filename, code.co_firstlineno, code.co_name)] = name
    stats = pstats.Stats(profiler).stats
    split = {}
    for key, s in stats.items():
        if key in kernels:
            split[kernels[key]] = split.get(kernels[key], 0.0) + s[2]
        elif key[0] == "~" and "mujoco" in key[2]:
            split["MuJoCo kinematics"] = split.get("MuJoCo kinematics", 0.0) + s[2]
    rest = whole_ms - 1e3 * sum(split.values()) / frames
    print(f"\nprofile (ms per frame of the unprofiled {whole_ms:.1f}, both passes)")
    for name, t in sorted(split.items(), key=lambda kv: -kv[1]):
        print(f"  {name:28s} {1e3 * t / frames:6.1f}  {100 * 1e3 * t / frames / whole_ms:4.0f}%")
    print(f"  {'Python and numpy':28s} {rest:6.1f}  {100 * rest / whole_ms:4.0f}%")


def add_phase_times(records: list, phases: dict, many: int = 10) -> None:
    """Add a run's causal frame times (``FrameRecord.ms``) to ``phases`` (name -> list of ms): the start (the
    first frame with tracks), the frames with more than ``many`` tracks, and the rest. The start and the frames
    of many tracks (every primitive's turns and twin alive) are where a clip's time goes."""
    tracked = [r for r in records if r.tracks]
    for i, r in enumerate(tracked):
        name = "the start" if i == 0 else (f"more than {many} tracks" if len(r.tracks) > many else
                                             f"{many} or fewer tracks")
        phases.setdefault(name, []).append(r.ms)


def print_phase_times(phases: dict) -> None:
    whole = sum(sum(v) for v in phases.values())
    print("\nthis engine's causal time by phase of a clip:")
    for name, times in phases.items():
        print(f"  {name:24s} {len(times):4d} frames  {np.mean(times):6.1f} ms/frame  {100 * sum(times) / whole:4.0f}% "
              "of the time")


def _machine() -> str:
    """The CPU as the kernels see it: its name, LLVM's name for its generation and its widest vectors (the
    engine's time differs by 1.5-1.8x between an Intel core with AVX-512 and an AMD Zen 3 with AVX2 only)."""
    import platform

    import llvmlite.binding as llvm

    features = llvm.get_host_cpu_features().flatten().split(",")
    vectors = "AVX-512" if "+avx512f" in features else "AVX2" if "+avx2" in features else "no AVX2"
    cpuinfo = Path("/proc/cpuinfo")
    names = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
             if line.startswith("model name")] if cpuinfo.exists() else []
    name = names[0] if names else platform.processor()
    return f"{name} ({llvm.get_host_cpu_name()}, {vectors}), {os.cpu_count()} cores"


def _knows_mirrored(commit: str) -> bool:
    """Whether the engine at ``commit`` reads both-handed database files."""
    done = subprocess.run(["git", "-C", str(ROOT), "grep", "-q", "mirrored", commit, "--", "harness/engine/database.py"],
                          capture_output=True)
    return done.returncode == 0


def main() -> None:
    from harness.body import BodyModel
    from harness.engine import MotionDatabase, Tracker, TrackerConfig
    from harness.engine.config import settings_from_strings
    from harness.motion.performer import CYCLIC
    from harness.motion.performer import CLASSES, demonstrations
    from harness.scene import CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneSpec
    from harness.scene.simulate import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--classes", nargs="*", default=["walk", "kick", "jumping_jack", "squat", "wave"])
    ap.add_argument("--particles", type=int, default=None, help="particles of both engines (default: each its own)")
    ap.add_argument("--points", type=int, default=None, help="model points of both engines (default: each its own)")
    ap.add_argument("--reference", default=DEFAULT_REFERENCE, help="git commit of the reference engine "
                                                                   "('none' to skip it)")
    ap.add_argument("--repeats", type=int, default=3, help="rounds of the clips, both engines taking each "
                                                             "clip in turn, for the ratio")
    ap.add_argument("--set", nargs="*", default=[], metavar="SECTION.FIELD=VALUE",
                    help="engine settings of this engine")
    ap.add_argument("--profile", action="store_true", help="also split this engine's time into numba kernels, "
                                                            "MuJoCo and the Python (with numpy) around them")
    args = ap.parse_args()
    body = BodyModel.load()
    rng = np.random.default_rng(0)
    train = [demonstrations(c, 1, rng, subject=s)[0] for c in CLASSES for s in range(6)]
    db = MotionDatabase(n_states=20, cyclic=CYCLIC).fit(train)
    # Engines before the both-handed database read a database file as one chain of all its states.
    one_sided = MotionDatabase(n_states=20, cyclic=CYCLIC, mirrored=False).fit(train)
    spec = SceneSpec(MarkerSpec(100, 1), CameraSpec(azimuth=40.0), OccluderSpec(), ObservationSpec(noise_px=1.0))
    clips = [simulate(demonstrations(c, 1, rng, subject=500 + i)[0], spec, rng, body)[0]
             for i, c in enumerate(["walk"] + args.classes)]                  # the first one warms up
    with tempfile.TemporaryDirectory() as tmp:
        db_path = Path(tmp) / "db.npz"
        (db if args.reference != "none" and _knows_mirrored(args.reference) else one_sided).save(db_path)
        obs_paths = []
        for i, obs in enumerate(clips):
            obs_paths.append(Path(tmp) / f"obs{i}.npz")
            obs.save(obs_paths[-1])
        t0 = time.perf_counter()
        sizes = {} if args.particles is None else {"tracks.particles": args.particles}
        sizes |= {} if args.points is None else {"model.points": args.points}
        settings = settings_from_strings(args.set)
        tracker = Tracker(db, body, TrackerConfig.from_dict(sizes | settings), rng=np.random.default_rng(1))
        print(f"machine: {_machine()}")
        print(f"database transform (once): {1e3 * (time.perf_counter() - t0):.0f} ms for "
              f"{db.means_.shape[0] * db.means_.shape[1]} states x {tracker.config.model.points} points, "
              f"{tracker.config.tracks.particles} particles")
        tracker.run(clips[0])
        total, causal, frames, parts, phases = 0.0, 0.0, 0, {}, {}
        for c, obs in zip(args.classes, clips[1:]):
            t1 = time.perf_counter()
            est = tracker.run(obs)
            total += time.perf_counter() - t1
            causal += 1e-3 * sum(est.timing.values()) * len(obs)
            frames += len(obs)
            for k, v in est.timing.items():
                parts[k] = parts.get(k, 0.0) + v * len(obs)
            add_phase_times(tracker.records, phases)
            print(f"{c:13s} {len(obs)} frames, {obs.counts[1:].mean():.0f} flows/frame, tracks "
                  f"{est.n_tracks.max()} -> {est.n_tracks[-1]}: {1e3 * (time.perf_counter() - t1) / len(obs):.1f} ms/frame")
        ms, whole = 1e3 * causal / frames, 1e3 * total / frames
        print(f"\nthis engine, causal (the loop a live camera needs): {ms:.1f} ms/frame ({1e3 / ms:.0f} fps); per "
              f"stage: " + ", ".join(f"{k} {v / frames:.1f} ms" for k, v in parts.items()))
        print(f"this engine, with the offline estimate (backward pass, evaluation only): {whole:.1f} ms/frame "
              f"({whole - ms:.1f} of it offline)")
        print_phase_times(phases)
        if args.profile:
            profiler = cProfile.Profile()
            profiler.enable()
            for obs in clips[1:]:
                tracker.run(obs)
            profiler.disable()
            print_profile(profiler, frames, whole)
        if args.reference != "none":
            mine, ref = side_by_side(args.reference, db_path, obs_paths, args.particles, args.points, args.repeats,
                                     settings)
            per_repeat = lambda t, i: 1e3 * t[..., i].sum(axis=1) / t[..., 2].sum(axis=1)  # noqa: E731
            print(f"\nside by side, each engine in a subprocess of its own, clip by clip in turns, {args.repeats} "
                  f"repeats; whole run (causal loop) ms/frame per repeat:")
            for name, t in (("this engine", mine), (args.reference, ref)):
                print(f"  {name:12s} " + ", ".join(f"{w:.1f} ({c:.1f})" for w, c in zip(per_repeat(t, 0),
                                                                                        per_repeat(t, 1))))
            rng = np.random.default_rng(0)
            for i, what in ((1, "causal loop"), (0, "whole run")):
                ratio, lo, hi = paired_ratio(mine[..., i].ravel(), ref[..., i].ravel(), rng)
                ms = 1e3 * mine[..., i].sum() / mine[..., 2].sum()
                ref_ms = 1e3 * ref[..., i].sum() / ref[..., 2].sum()
                print(f"{what}: this engine {ms:.1f} ms/frame ({1e3 / ms:.0f} fps), {args.reference} {ref_ms:.1f}; "
                      f"{args.reference} / this engine {ratio:.2f}x [{lo:.2f}, {hi:.2f}] (95%, {mine[..., i].size} "
                      f"clip pairs)")


if __name__ == "__main__":
    main()
