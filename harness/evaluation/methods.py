"""The evaluation's methods, registered by name: what each is handed, the estimate it produces, and the one
scorer that turns an estimate and the ground truth into a row.

A method is one function ``estimate(inputs: RunInputs, engine: EngineRuns) -> Estimate | None`` (None: nothing
to estimate, e.g. a camera that saw no flow), registered with ``method``. ``score`` turns the estimate into the
row's metric columns: recognition (or, on a stream, the stream columns) when the method recognises, recovery
when it recovers, the reproduction columns when it reproduces; a column a method does not produce is left
empty. The pipeline runs every method a scenario lists through this registry, the scenario validates
``methods`` against it, and the tables, plots and report take their order and their ``given`` / ``–`` cells
from it: adding a method is one registration here.

- ``full``: the engine from flows alone (pose tracks, recognition, recovery), causal: frame t from frames <= t;
- ``full_smoothed``: the same run's offline estimate (the track with the most evidence at the end, its whole
  trajectory smoothed; the final class posterior at every frame): what hindsight adds, for evaluation;
- ``gt_base``: the engine handed the true baselink pose (isolates recognition and recovery from tracking);
- ``no_database``: per-frame fitting of the angles to the 2D points at the true baselink pose, without the
  HMM prior (what the database's prior adds, compared with ``gt_base``); no recognition;
- ``bottom_up``: the bottom-up posture estimator alone, frame by frame (``harness.engine.bottom_up``: base pose up to
  the twin, angles), without recognition: what the learned part knows by itself;
- ``joint_space``: forward recognition from the true joint-space features (the upper bound); no recovery;
- ``reproduction`` (only when a scenario lists it): the ``full`` estimate, then the recognised primitive's
  reproduction along the recovered state path (``harness.engine.reproduction``), compared after dynamic time
  warping with the demonstration, beside the true class's mean trajectory (``REPRODUCTION_COLUMNS``).

Methods from outside the package (``harness.evaluation.external``): a scenario may name ``module.path:function``
or a method an installed package registers under the entry-point group ``harness.methods``; the function follows
the same protocol (version ``PROTOCOL_VERSION``, ``docs/methods.md``) and says which columns it produces with
``declare``. Its estimate is checked (``check_estimate``) before it is scored, and an exception it raises marks its
own row failed (``run_method``) while the evaluation goes on.

The engine runs at most once per run and pose source (``EngineRuns``): ``full``, ``full_smoothed`` and
``reproduction`` share one run.

On a stream (``RunInputs.labels`` given) the methods that recognise are scored per frame with the stream
columns (``harness.evaluation.stream_metrics``) instead of one label per run; their recognised segments are kept
in the row (``segments_pred``) for the timeline plots.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from harness import geometry
from harness.body import BodyModel, SurfacePoints, body_origins
from harness.engine import Estimate, MotionDatabase, Tracker, TrackerConfig, motion_features, recognize_features
from harness.engine.bottom_up import WINDOW
from harness.engine.database import UNKNOWN
from harness.engine.features import measured_features
from harness.engine.recovery import fit_without_database
from harness.engine.switching import STREAM_MIN_FRAMES, online_labels, recognize_stream_features
from harness.errors import HarnessError
from harness.evaluation import metrics
from harness.evaluation.stream_metrics import STREAM_COLUMNS, stream_scores
from harness.motion.stream import label_segments
from harness.motion import Motion
from harness.observation import Observation
from harness.scene.simulate import GroundTruth
from harness.scene.spec import SceneSpec

RECOGNITION_COLUMNS = ("class_pred", "correct", "frame_accuracy", "time_to_correct_s", "log_p_true",
                       "accuracy_curve", "confidence", "posterior_final", "p_unknown")
RECOVERY_COLUMNS = ("angle_rms_deg", "mpjpe_pose_mm", "mpjpe_cam_mm", "mpjpe_cam17_mm", "pa_mpjpe_mm",
                    "pa_mpjpe17_mm", "mpjpe_abs_mm", "base_pos_err_m", "base_depth_err_m", "base_rot_err_deg",
                    "heading_err_deg", "tilt_err_deg", "reproj_px", "heading_err_twin_deg", "on_twin", "heading_curve")
BASE_POSE_COLUMNS = ("base_pos_err_m", "base_depth_err_m", "base_rot_err_deg", "heading_err_deg", "tilt_err_deg",
                     "heading_err_twin_deg", "on_twin", "heading_curve")
# A run settled on the twin (``on_twin``): its mean heading error beyond a quarter turn, and its error up to the
# depth-reflected mirrored twin within 45 degrees (the rule of ``tables.heading_spread``).
TWIN_RUN_DEG, TWIN_NEAR_DEG = 90.0, 45.0
CURVE_POINTS = 10       # accuracy_curve, heading_curve: at 10 evenly spaced fractions of the clip
STREAM_RECOGNITION_COLUMNS = STREAM_COLUMNS + ("segments_pred",)
REPRODUCTION_COLUMNS = ("repro_dtw_deg", "repro_dtw_mm", "mean_dtw_deg", "mean_dtw_mm", "repro_beats_mean")


@dataclass(frozen=True)
class RunInputs:
    """What a method may use in one run (the scorer sees the truth; the engine's inputs are obs and db).

    body: the engine's nominal body. subject: the observed body (``body`` itself unless the scenario scales
    the subject). motion: the test motion as the subject performed it. truth: the scene's ground truth.
    tracker: a fresh engine (own random generator) on every call. labels: a stream's true label per frame
    ``(T,)`` (``label`` is then ``"stream"``), None for one primitive. engine: the engine's settings. scene: the
    run's scene spec as drawn (camera azimuth, marker and occluder seeds), and performed: the test motion as the
    nominal body performed it; with them the scene can be built again (``harness run-video``) without drawing.
    """

    key: str
    label: str
    classes: tuple[str, ...]
    body: BodyModel
    subject: BodyModel
    db: MotionDatabase
    motion: Motion
    obs: Observation
    truth: GroundTruth
    tracker: Callable[[], Tracker]
    labels: np.ndarray | None = None
    engine: TrackerConfig = TrackerConfig()
    scene: SceneSpec | None = None
    performed: Motion | None = None

    @property
    def recognition_columns(self) -> tuple[str, ...]:
        return RECOGNITION_COLUMNS if self.labels is None else STREAM_RECOGNITION_COLUMNS

    @property
    def open_set(self) -> bool:
        """Whether the test motion is of no class the database has (a capture row of ``other``, say): scored
        for what each method answered and how sure it was, never in an accuracy."""
        return self.labels is None and self.label not in self.classes

    @cached_property
    def true_joints(self) -> tuple[np.ndarray, np.ndarray]:
        """The subject's true joint centres ``(T, J, 3)`` in the camera frame and in its base frame, computed
        once for every method the run scores."""
        truth = self.truth
        true_cam = metrics.camera_qpos(self.subject, truth.base_pos_cam, truth.base_quat_cam, truth.qpos[:, 7:])
        return body_origins(self.subject, true_cam, frame="world"), body_origins(self.subject, true_cam, frame="base")


class EngineRuns:
    """The engine's runs of one evaluation run, each made on first use and kept: from the flows alone, and
    handed the true base pose (None when the camera saw no flow)."""

    def __init__(self, inputs: RunInputs):
        self.inputs = inputs

    @cached_property
    def from_flows(self) -> Estimate | None:
        return self._run(None)

    @cached_property
    def given_pose(self) -> Estimate | None:
        return self._run((self.inputs.truth.base_pos_cam, self.inputs.truth.base_quat_cam))

    def _run(self, base_pose) -> Estimate | None:
        if self.inputs.obs.counts.sum() == 0:        # nothing seen: nothing to score (NaN, counted as missing)
            return None
        return self.inputs.tracker().run(self.inputs.obs, base_pose=base_pose)


@dataclass(frozen=True)
class Method:
    """A registered method. recognises/recovers/reproduces: which columns its estimate is scored on (``–`` in
    the report otherwise). given: columns it is handed rather than estimating (``given``). version: for a method
    from outside the package, its code's version (``external.source_version``), stamped on its rows; empty for
    the built-in ones (the package's own code version is in every scenario hash)."""

    name: str
    estimate: Callable[[RunInputs, EngineRuns], Estimate | None]
    recognises: bool
    recovers: bool
    given: tuple[str, ...] = ()
    default: bool = True
    reproduces: bool = False
    version: str = ""

    @property
    def external(self) -> bool:
        return bool(self.version)


METHODS: dict[str, Method] = {}
EXTERNAL: dict[str, Method] = {}      # methods from outside the package, as resolved (``external.resolve``)
PROTOCOL_VERSION = 1                  # of ``estimate(inputs, engine) -> Estimate | None`` (docs/methods.md)
DECLARATION = "harness_method"        # the attribute ``declare`` sets on a function from outside the package


class MethodError(HarnessError):
    """A method from outside the package that cannot be used: not importable, not declared, or an estimate that
    breaks the protocol; the message names the method."""


def declare(recognises: bool, recovers: bool, given: tuple[str, ...] = (), protocol: int = PROTOCOL_VERSION):
    """Declare a function outside the package a method of protocol ``protocol``: which columns its estimate is
    scored on (``recognises``: the recognition or stream columns from ``class_posterior``; ``recovers``: the
    recovery columns from ``qpos``) and which of those it is handed rather than estimating (``given``, e.g.
    ``BASE_POSE_COLUMNS`` for a method handed the true base pose). Sets ``function.harness_method``, which a
    package may also set by hand (a mapping of these four keys) to avoid importing the harness."""
    def mark(fn):
        setattr(fn, DECLARATION, {"protocol": protocol, "recognises": recognises, "recovers": recovers,
                                  "given": tuple(given)})
        return fn
    return mark


def known(name: str) -> Method | None:
    """The built-in or already resolved method of that name, or None (no import is tried)."""
    return METHODS.get(name) or EXTERNAL.get(name)


def method(name: str, recognises: bool, recovers: bool, given: tuple[str, ...] = (), default: bool = True,
           reproduces: bool = False):
    """Register ``estimate(inputs, engine) -> Estimate | None`` under ``name`` (registration order is the
    report's order). ``default``: run when a scenario does not list its methods."""
    def register(estimate: Callable[[RunInputs, EngineRuns], Estimate | None]):
        METHODS[name] = Method(name, estimate, recognises, recovers, given, default, reproduces)
        return estimate
    return register


def method_names() -> tuple[str, ...]:
    return tuple(METHODS)


def default_methods() -> tuple[str, ...]:
    """The methods a scenario runs when it does not list them."""
    return tuple(m.name for m in METHODS.values() if m.default)


def produces(name: str, column: str) -> bool:
    """Whether method ``name`` produces ``column`` (recognition, recovery and reproduction columns; others
    always)."""
    m = known(name)
    if m is None:
        return True
    if column in RECOGNITION_COLUMNS or column in STREAM_RECOGNITION_COLUMNS:
        return m.recognises
    if column in RECOVERY_COLUMNS:
        return m.recovers
    if column in REPRODUCTION_COLUMNS:
        return m.reproduces
    return True


# --- scoring ----------------------------------------------------------------------------------------------

def accuracy_curve(posteriors: np.ndarray, classes, label: str, points: int = CURVE_POINTS) -> list[int]:
    """Whether the argmax is the true class at frames ``round(k (T - 1) / (points - 1))``, ``k = 0..points-1``:
    a compact per-run record of recognition against time since the start of the motion."""
    post = np.asarray(posteriors, dtype=float)
    frames = np.round(np.linspace(0, len(post) - 1, points)).astype(int)
    return [int(v) for v in np.argmax(post[frames], axis=1) == list(classes).index(label)]


def recognition_scores(post: np.ndarray, classes, label: str, fps: float) -> dict:
    """Recognition columns of class posteriors ``(T, C)``; ``confidence`` and ``posterior_final`` (``{class:
    probability}`` of the last frame, the posterior that decides ``class_pred``) are what
    ``harness.evaluation.calibration`` scores."""
    out = metrics.recognition(post, classes, label, fps)      # checks the shape and the label first
    final = np.asarray(post, dtype=float)[-1]
    return out | {"log_p_true": metrics.log_p_true(post, classes, label),
                  "accuracy_curve": accuracy_curve(post, classes, label), "confidence": float(final.max()),
                  "posterior_final": {str(c): float(p) for c, p in zip(classes, final)},
                  "p_unknown": p_unknown(final, classes)}


def p_unknown(final: np.ndarray, classes) -> float:
    """The final probability of the database's background class ``unknown`` ("none of these"), NaN for a
    database without one."""
    classes = [str(c) for c in classes]
    return float(final[classes.index(UNKNOWN)]) if UNKNOWN in classes else float("nan")


def segment_list(labels) -> list[list]:
    """Per-frame labels as ``[[label, start, stop], ...]`` (a row's compact record of a labelling)."""
    return [[seg.label, seg.start, seg.stop] for seg in label_segments(labels)]


def stream_recognition_scores(post: np.ndarray, classes, labels: np.ndarray, fps: float) -> dict:
    """Stream columns of class posteriors ``(T, C)`` against the true labels per frame: the online labels
    (``engine.switching.online_labels``) scored with ``stream_metrics``, and their segments."""
    recognised = np.asarray(classes)[online_labels(post, STREAM_MIN_FRAMES)]
    return stream_scores(recognised, labels, fps) | {"segments_pred": segment_list(recognised)}


def open_set_scores(post: np.ndarray, classes) -> dict:
    """Recognition columns of a motion of no known class: what was answered and how surely; the columns that
    need a true class stay empty."""
    final = np.asarray(post, dtype=float)[-1]
    return not_produced(RECOGNITION_COLUMNS) | {
        "class_pred": str(classes[int(np.argmax(final))]), "confidence": float(final.max()),
        "posterior_final": {str(c): float(p) for c, p in zip(classes, final)}, "p_unknown": p_unknown(final, classes)}


def _recognition(inputs: RunInputs, post: np.ndarray, fps: float) -> dict:
    if inputs.labels is not None:
        return stream_recognition_scores(post, inputs.classes, inputs.labels, fps)
    if inputs.open_set:
        return open_set_scores(post, inputs.classes)
    return recognition_scores(post, inputs.classes, inputs.label, fps)


def nominal_markers(markers: SurfacePoints, subject: BodyModel) -> SurfacePoints:
    """The markers' corresponding points on the nominal body: each segment of the subject is a uniformly
    scaled copy of the nominal one (``harness.body.scaling``), so body-frame coordinates divide by its factor."""
    factor = subject.segment_scale[markers.body][:, None]
    return SurfacePoints(markers.body, markers.geom, markers.local / factor, markers.normal)


def recovery_scores(inputs: RunInputs, qpos_est: np.ndarray) -> dict:
    """Recovery columns of an estimate ``(T, 57)`` (camera-frame base). True joints are the observed
    subject's (a scaled subject's joints are where that subject's are; docs/evaluation.md)."""
    body, subject, truth, obs = inputs.body, inputs.subject, inputs.truth, inputs.obs
    frame = np.concatenate([np.full(len(i), t) for t, i in enumerate(truth.marker_ids)]).astype(int)
    marker = np.concatenate(truth.marker_ids).astype(int)
    uv = np.concatenate([f[:, :2] for f in obs.flows])
    keep = marker >= 0
    h36m = metrics.h36m_joints(body)
    out = {"angle_rms_deg": metrics.angle_rms_deg(qpos_est[:, 7:], truth.qpos[:, 7:])}
    true_world, true_base = inputs.true_joints
    out |= metrics.joint_errors_mm(body_origins(body, qpos_est, frame="world"), true_world,
                                   body_origins(body, qpos_est, frame="base"), true_base, h36m)
    out["reproj_px"] = metrics.reprojection_px(body, qpos_est, nominal_markers(truth.markers, subject),
                                               obs.intrinsics, frame[keep], marker[keep], uv[keep])
    out |= metrics.base_errors(qpos_est[:, :3], qpos_est[:, 3:7], truth.base_pos_cam, truth.base_quat_cam)
    out |= metrics.heading_tilt_errors(qpos_est[:, 3:7], truth.base_quat_cam, truth.camera_rot)
    out |= metrics.heading_twin_error(qpos_est[:, 3:7], truth.base_quat_cam, truth.camera_rot)
    out["on_twin"] = int(out["heading_err_deg"] > TWIN_RUN_DEG and out["heading_err_twin_deg"] <= TWIN_NEAR_DEG)
    out["heading_curve"] = metrics.heading_error_curve(qpos_est[:, 3:7], truth.base_quat_cam, truth.camera_rot,
                                                       CURVE_POINTS)
    return out


def not_produced(columns: tuple[str, ...]) -> dict:
    return {c: ("" if c == "class_pred" else [] if c in ("accuracy_curve", "heading_curve", "segments_pred")
                else {} if c == "posterior_final" else np.nan) for c in columns}


def reproduction_scores(inputs: RunInputs, est: Estimate) -> dict:
    """The reproduction columns of an estimate carrying a reproduction, against the demonstration and beside
    the true class's mean trajectory."""
    from harness.engine.reproduction import class_mean
    from harness.evaluation.reproduction_metrics import dtw_angle_rms_deg, dtw_mpjpe_mm

    repro, demo, fps = est.reproduction, inputs.motion, inputs.obs.fps
    mean = class_mean(inputs.db, inputs.body, inputs.label, demo.n_frames, fps)
    out = {"repro_dtw_deg": dtw_angle_rms_deg(repro.angles, demo.angles),
           "repro_dtw_mm": dtw_mpjpe_mm(inputs.body, repro.qpos, inputs.subject, demo.qpos),
           "mean_dtw_deg": dtw_angle_rms_deg(mean.angles, demo.angles),
           "mean_dtw_mm": dtw_mpjpe_mm(inputs.body, mean.qpos, inputs.subject, demo.qpos)}
    return {"class_pred": est.predicted} | out | {"repro_beats_mean": int(out["repro_dtw_deg"] < out["mean_dtw_deg"])}


def score(m: Method, est: Estimate | None, inputs: RunInputs) -> dict:
    """The metric columns of method ``m``'s estimate of one run against its ground truth (module docstring).
    A reproducing method is scored on its reproduction alone."""
    if m.reproduces:
        if est is None or est.reproduction is None:
            return {c: np.nan for c in REPRODUCTION_COLUMNS}
        return reproduction_scores(inputs, est)
    recognised = (_recognition(inputs, est.class_posterior, inputs.obs.fps) if m.recognises and est is not None
                  else not_produced(inputs.recognition_columns))
    recovered = (recovery_scores(inputs, est.qpos) if m.recovers and est is not None
                 else not_produced(RECOVERY_COLUMNS))
    return recognised | recovered


def check_estimate(m: Method, est: Estimate | None, inputs: RunInputs) -> None:
    """``MethodError`` naming the method when its estimate breaks the protocol: not an ``Estimate`` (or None);
    ``classes`` other than ``inputs.classes`` in that order; a recognising method's ``class_posterior`` not
    ``(T, C)`` with finite non-negative rows summing to 1; a recovering method's ``qpos`` not ``(T, 57)`` and
    finite (``T``: the observation's frames)."""
    if est is None:
        return
    if not isinstance(est, Estimate):
        raise MethodError(f"method {m.name!r} returned {type(est).__name__}, not an Estimate or None")
    n, classes = len(inputs.obs), tuple(inputs.classes)
    if m.recognises:
        if tuple(str(c) for c in np.asarray(est.classes).tolist()) != classes:
            raise MethodError(f"method {m.name!r}: Estimate.classes must be inputs.classes {list(classes)} in that "
                              f"order, got {np.asarray(est.classes).tolist()}")
        post = None if est.class_posterior is None else np.asarray(est.class_posterior, dtype=float)
        if post is None or post.shape != (n, len(classes)):
            got = "None" if post is None else str(post.shape)
            raise MethodError(f"method {m.name!r} recognises: class_posterior must be ({n}, {len(classes)}) (frames x "
                              f"classes), got {got}")
        if not np.all(np.isfinite(post)) or np.any(post < 0) or not np.allclose(post.sum(axis=1), 1.0, atol=1e-6):
            raise MethodError(f"method {m.name!r}: class_posterior rows must be finite, non-negative and sum to 1")
    if m.recovers:
        qpos = None if est.qpos is None else np.asarray(est.qpos, dtype=float)
        if qpos is None or qpos.shape != (n, 57):
            raise MethodError(f"method {m.name!r} recovers: qpos must be ({n}, 57), got "
                              f"{'None' if qpos is None else qpos.shape}")
        if not np.all(np.isfinite(qpos)):
            raise MethodError(f"method {m.name!r}: qpos must be finite")


FAILED_MESSAGE_CHARS = 300     # a failed row keeps the first line of its error, cut to this


def first_line(exc: BaseException) -> str:
    """``Type: first line of the message`` (what a failed row records)."""
    lines = str(exc).strip().splitlines()
    text = f"{type(exc).__name__}: {lines[0]}" if lines else type(exc).__name__
    return text if len(text) <= FAILED_MESSAGE_CHARS else text[:FAILED_MESSAGE_CHARS - 3] + "..."


def failed_scores(m: Method, inputs: RunInputs, message: str) -> dict:
    """The columns of a row whose method failed: every metric empty, ``failed`` the message."""
    columns = ((REPRODUCTION_COLUMNS if m.reproduces else ()) + (inputs.recognition_columns if m.recognises else ())
               + (RECOVERY_COLUMNS if m.recovers else ()))
    return not_produced(columns) | {"failed": message}


def run_method(m: Method, inputs: RunInputs, engine: EngineRuns) -> dict:
    """The metric columns of one method on one run. A method from outside the package is isolated: an exception
    it raises, or an estimate that breaks the protocol, makes its row failed (``failed``: the error's first line)
    and the evaluation goes on; its rows carry ``method_version``. A built-in method's exception is the harness's
    own bug and keeps its traceback."""
    if not m.external:
        return score(m, m.estimate(inputs, engine), inputs)
    stamp = {"method_version": m.version}
    try:
        est = m.estimate(inputs, engine)
        check_estimate(m, est, inputs)
        return score(m, est, inputs) | {"failed": ""} | stamp
    except Exception as exc:                # the method's own failure: its row, not the evaluation
        return failed_scores(m, inputs, first_line(exc)) | stamp


# --- the methods ------------------------------------------------------------------------------------------

@method("full", recognises=True, recovers=True)
def _full(inputs: RunInputs, engine: EngineRuns) -> Estimate | None:
    return engine.from_flows


@method("full_smoothed", recognises=True, recovers=True)
def _full_smoothed(inputs: RunInputs, engine: EngineRuns) -> Estimate | None:
    return None if engine.from_flows is None else engine.from_flows.offline


@method("gt_base", recognises=True, recovers=True, given=BASE_POSE_COLUMNS)
def _gt_base(inputs: RunInputs, engine: EngineRuns) -> Estimate | None:
    return engine.given_pose


@method("no_database", recognises=False, recovers=True, given=BASE_POSE_COLUMNS)
def _no_database(inputs: RunInputs, engine: EngineRuns) -> Estimate:
    tracker = inputs.tracker()
    truth = inputs.truth
    angles = fit_without_database(inputs.body, tracker.model.points, inputs.obs.intrinsics, inputs.obs.flows,
                                  truth.base_pos_cam, truth.base_quat_cam, noise_px=tracker.config.likelihood.noise_px,
                                  spread=tracker.model.spread)
    qpos = metrics.camera_qpos(inputs.body, truth.base_pos_cam, truth.base_quat_cam, angles)
    return Estimate(np.asarray(inputs.classes), qpos=qpos)


@method("bottom_up", recognises=False, recovers=True)
def _bottom_up(inputs: RunInputs, engine: EngineRuns) -> Estimate | None:
    """The bottom-up estimator alone, frame by frame (``harness.engine.bottom_up``): each frame's base pose and
    angles from the window of flows ending there, the canonical member of the twin pair (it cannot tell the
    two apart), no recognition; a frame without an estimate takes the nearest earlier one (the first one before
    it)."""
    from harness.engine.bottom_up import load_model

    model, obs = load_model(), inputs.obs
    est = [model.estimate(obs.flows[max(0, t - WINDOW + 1):t + 1], obs.intrinsics, obs.fps) for t in range(len(obs))]
    seen = [e for e in est if e is not None]
    if not seen:
        return None
    last, rows = seen[0], []
    for e in est:
        last = e if e is not None else last
        rows.append(np.concatenate([last.position, geometry.from_matrix(last.rotation), last.features[:50]]))
    return Estimate(np.asarray(inputs.classes), qpos=np.array(rows))


@method("joint_space", recognises=True, recovers=False)
def _joint_space(inputs: RunInputs, engine: EngineRuns) -> Estimate:
    features, measured = motion_features(inputs.motion), measured_features(inputs.motion)
    switch = inputs.engine.belief.primitive_switch
    post = (recognize_stream_features(inputs.db, features, switch, inputs.engine.belief.start_spread,
                                      measured=measured)
            if switch > 0 else recognize_features(inputs.db, features, measured=measured))
    return Estimate(np.asarray(inputs.classes), class_posterior=post)


@method("reproduction", recognises=False, recovers=False, default=False, reproduces=True)
def _reproduction(inputs: RunInputs, engine: EngineRuns) -> Estimate | None:
    from harness.engine.reproduction import reproduce, state_path

    est = engine.from_flows
    if inputs.labels is not None or est is None:       # one primitive per run, and something seen
        return None
    label = est.predicted
    repro = reproduce(inputs.db, inputs.body, label, state_path(inputs.db, est.joint_posterior, label),
                      inputs.obs.fps, angles=est.qpos[:, 7:])
    return replace(est, reproduction=repro)
