"""The performer's ten whole-body primitives (written in anatomical degrees; see ``primitives``).

Cyclic primitives (walk, run, jumping_jack, wave) perform about two cycles from a random starting phase;
discrete ones perform one execution between two rests of random length. Every amplitude below is multiplied
by the take's ``amp`` and every duration by its ``tempo``. Confusable pairs are intended: walk/run share the
gait pattern, punch/throw the right arm driven forward by a trunk twist, squat/bow/jump the hip flexion.
"""

from __future__ import annotations

import numpy as np

from harness.motion.primitives import Plan, Take, bump, primitive

TAU = 2.0 * np.pi


def _gait(k: Take, phase: np.ndarray, hip: float, knee_swing: float, knee_stance: float, swing_peak: float,
          arm: float, elbow: float, elbow_swing: float, lean: float, push: float) -> None:
    """Shared leg, arm and trunk pattern of walking and running.

    ``phase`` (T,) is the left leg's phase: hip most flexed at pi/2 (heel strike), most extended at -pi/2
    (toe-off); the right leg runs half a cycle behind. Arms swing opposite to the leg of their side.
    """
    a = k.amp
    for side, ph in (("l", phase), ("r", phase + np.pi)):
        hip_y = -hip * a * np.sin(ph) - 4.0
        knee = 4.0 + knee_swing * a * bump(ph, swing_peak, 3.0) + knee_stance * a * bump(ph, np.pi / 2 + 0.7, 6.0)
        toe = -25.0 * a * bump(ph, -1.9, 10.0)
        arm_y = arm * a * np.sin(ph)                       # left arm back when the left leg is forward
        elb = -(elbow + elbow_swing * a * 0.5 * (1.0 - np.sin(ph)))
        k.add(side + "femur_y", hip_y)
        k.add(side + "tibia_y", knee)
        k.add(side + "toes_y", toe)
        k.add(side + "humerus_y", arm_y)
        k.add(side + "radius_y", elb)
        k.add(side + "femur_z", (3.0 if side == "l" else -3.0) * a * np.sin(ph))
    k.both("humerus_x", 8.0)
    k.both("femur_x", 2.0)
    # Pelvis turns with the forward leg (left leg forward = turn right); the thorax counter-rotates.
    k.yaw += -5.0 * a * np.sin(phase)
    k.spine("z", 9.0 * a * np.sin(phase))
    k.neck("z", -4.0 * a * np.sin(phase))
    k.lean(roll=3.0 * a * np.cos(phase))                   # pelvis drops on the swing side
    k.lean(pitch=lean + 2.0 * a * np.cos(2.0 * phase))
    k.spine("y", 0.5 * lean + 2.0 * np.cos(2.0 * phase))
    k.neck("y", -0.8 * lean)                              # keep the gaze level
    # Soles parallel to the floor except at push-off, where the heel rises (plantar flexion on top of the
    # leg's own inclination), and just before heel strike, where the toes come up.
    # In swing the ankle only half follows the knee: a fully flat swinging foot would need more dorsiflexion
    # than the ankle has, and a hanging one would drag its toes.
    push_l, push_r = bump(phase, -1.9, 4.0), bump(phase + np.pi, -1.9, 4.0)
    flat_l = np.maximum(bump(phase, np.pi, 2.0), 0.5)
    flat_r = np.maximum(bump(phase + np.pi, np.pi, 2.0), 0.5)
    k.flat_feet(flat_l * (1.0 - push_l), flat_r * (1.0 - push_r))
    for side, ph, pb in (("l", phase, push_l), ("r", phase + np.pi, push_r)):
        k.add(side + "foot_y", a * (push * pb - 10.0 * bump(ph, np.pi / 2 - 0.2, 8.0)))


@primitive("walk", cyclic=True)
def walk(k: Take) -> Plan:
    # From a stroll (straight arms) to a power walk (long stride, bent elbows, leaning into it).
    brisk = k.rng.uniform(0.0, 1.0)
    period = k.period(0.95, 1.1)
    cycles = k.cycles(1.75, 2.0) - 0.2 * brisk             # <= 3 m even for a brisk walker
    t = k.begin(cycles * period)
    phase = TAU * t / period + k.rng.uniform(0.0, TAU)
    _gait(k, phase, hip=18.0 + 5.0 * brisk, knee_swing=50.0 + 15.0 * brisk, knee_stance=12.0, swing_peak=-0.5,
          arm=12.0 + 14.0 * brisk, elbow=8.0 + 70.0 * brisk * k.rng.uniform(0.3, 1.0), elbow_swing=12.0,
          lean=k.rng.uniform(0.0, 3.0) + 3.0 * brisk, push=18.0)
    return k.plan()


@primitive("run", cyclic=True)
def run(k: Take) -> Plan:
    # Intensity from a relaxed jog (short stride, low heels, arms half bent) to a stride.
    effort = k.rng.uniform(0.0, 1.0)
    period = k.period(0.66, 0.72)
    cycles = k.cycles(1.35, 1.55) - 0.15 * effort            # shorter: a runner covers ~3 m in ~1 s
    t = k.begin(cycles * period)
    phase = TAU * t / period + k.rng.uniform(0.0, TAU)
    _gait(k, phase, hip=26.0 + 10.0 * effort, knee_swing=60.0 + 45.0 * effort, knee_stance=25.0 + 8.0 * effort,
          swing_peak=-0.2, arm=18.0 + 14.0 * effort, elbow=k.rng.uniform(40.0, 90.0), elbow_swing=15.0,
          lean=3.0 + 8.0 * effort, push=30.0)
    # Airborne between toe-off of one leg and touch-down of the other: stance of the left leg is the
    # stretch of phase within 0.3 pi of pi (mid-stance), of the right leg within 0.3 pi of 0.
    wrapped = np.mod(phase, np.pi)                         # both legs' stance centres map to 0 / pi
    k.flight[:] = (wrapped > 0.3 * np.pi) & (wrapped < 0.7 * np.pi)
    return k.plan()


@primitive("jump")
def jump(k: Take) -> Plan:
    """Counter-movement jump: crouch with the arms back, extend and swing the arms up, fly, land, recover."""
    a = k.amp
    t0 = k.span(0.2, 0.7)
    t1 = t0 + k.span(0.5, 0.6)                             # bottom of the crouch
    t2 = t1 + k.span(0.18, 0.22)                           # take-off
    t3 = t2 + k.rng.uniform(0.36, 0.44) * np.sqrt(a)       # landing: flight time sets the height
    t4 = t3 + k.span(0.18, 0.22)                           # deepest landing
    t5 = t4 + k.span(0.5, 0.7)
    t = k.begin(t5 + k.span(0.2, 0.7))
    depth = k.rng.uniform(0.6, 1.0)
    crouch = k.keys((t0, 0.0), (t1, depth), (t2, 0.0), (t3, 0.0), (t4, 0.7 * depth), (t5, 0.0))
    arms_up = k.keys((t1 - 0.12, 0.0), (t2, 1.0), (t3, 0.8), (t4, 0.2), (t5, 0.0))   # swing starts early
    tuck = k.keys((t2, 0.0), (0.5 * (t2 + t3), 1.0), (t3, 0.0))
    push = k.keys((t1, 0.0), (t2, 1.0), (t2 + 0.1, 0.3), (t3, 0.0))
    k.lean(pitch=a * (26.0 * crouch + 4.0 * tuck))
    k.both("femur_y", a * (-68.0 * crouch - 35.0 * tuck))
    k.both("tibia_y", a * (68.0 * crouch + 40.0 * tuck))
    k.spine("y", a * 18.0 * crouch)
    k.neck("y", -20.0 * a * crouch)
    # Arm swing from overhead (reach 1) to back and down (reach 0: CMU subject 1's forward jumps, whose
    # humeri extend 25 deg at take-off); elbows carried bent (CMU: 105 deg) straighten with the swing.
    reach = k.rng.uniform(0.0, 1.0)
    carry = k.rng.uniform(15.0, 100.0)
    k.both("humerus_y", a * (45.0 * crouch - (150.0 * reach - 30.0 * (1.0 - reach)) * arms_up))
    k.both("radius_y", -15.0 - carry * (1.0 - arms_up) - 10.0 * reach * arms_up)
    k.both("humerus_x", 10.0 * arms_up)
    k.flat_feet(1.0 - push)
    k.both("foot_y", 35.0 * a * push)
    k.both("toes_y", -30.0 * a * k.keys((t1, 0.0), (t2, 1.0), (t2 + 0.12, 0.0)))   # toes bend at take-off
    k.flight[:] = (t >= t2) & (t < t3)
    return k.plan(flight_speed=k.rng.uniform(0.3, 0.8))


@primitive("squat")
def squat(k: Take) -> Plan:
    a = k.amp
    t0 = k.span(0.2, 0.7)
    t1 = t0 + k.span(0.7, 0.9)
    t2 = t1 + k.span(0.15, 0.35)
    t3 = t2 + k.span(0.7, 0.9)
    k.begin(t3 + k.span(0.2, 0.7))
    depth = k.rng.uniform(0.7, 1.0)                        # half squat to full squat
    s = k.keys((t0, 0.0), (t1, 1.0), (t2, 1.0), (t3, 0.0)) * a * depth
    arms = k.keys((t0, 0.0), (t1 - k.scaled(0.2), 1.0), (t2, 1.0), (t3, 0.0)) * a * k.rng.uniform(0.3, 1.0)
    lean = k.rng.uniform(12.0, 32.0)                       # upright or hips-back squat
    k.lean(pitch=lean * s)
    k.both("femur_y", -(66.0 + lean) * s)
    k.both("tibia_y", 96.0 * s)
    k.both("femur_x", 8.0 * s)                             # knees track outward over the toes
    k.spine("y", 14.0 * s)
    k.neck("y", -30.0 * s)
    k.both("humerus_y", -80.0 * arms)
    k.both("radius_y", -8.0 - 10.0 * arms)
    k.flat_feet(1.0)
    return k.plan()


@primitive("bow")
def bow(k: Take) -> Plan:
    a = k.amp
    t0 = k.span(0.2, 0.7)
    t1 = t0 + k.span(0.6, 0.8)
    t2 = t1 + k.span(0.3, 0.5)
    t3 = t2 + k.span(0.7, 0.9)
    k.begin(t3 + k.span(0.2, 0.7))
    s = k.keys((t0, 0.0), (t1, 1.0), (t2, 1.0), (t3, 0.0)) * a * k.rng.uniform(0.7, 1.0)
    knees = k.rng.uniform(0.0, 20.0)                       # some bow with soft knees
    k.lean(pitch=28.0 * s)
    k.both("femur_y", -(24.0 + knees) * s)                 # legs stay near vertical under a tipped pelvis
    k.both("tibia_y", (6.0 + 1.5 * knees) * s)
    k.spine("y", 45.0 * s)
    k.neck("y", 15.0 * s)
    k.both("humerus_y", -50.0 * s)                         # arms hang from the bent trunk
    k.both("humerus_x", -6.0 * s)
    k.both("radius_y", -10.0 - 15.0 * s)
    k.flat_feet(1.0)
    return k.plan()


@primitive("kick")
def kick(k: Take) -> Plan:
    """Right front kick: guard up, chamber the knee, snap the shank out, retract, put the foot down."""
    a = k.amp
    t0 = k.span(0.2, 0.7)
    t1 = t0 + k.span(0.35, 0.45)                           # knee chambered
    t2 = t1 + k.span(0.12, 0.18)                           # leg extended
    t3 = t2 + k.span(0.18, 0.25)                           # re-chambered
    t4 = t3 + k.span(0.35, 0.45)                           # foot down
    k.begin(t4 + k.span(0.2, 0.7))
    guard = k.keys((t0 - 0.2, 0.0), (t0 + 0.2, 1.0), (t4, 1.0), (t4 + 0.3, 0.0))
    hip = k.keys((t0, 0.0), (t1, 0.8), (t2, 1.0), (t3, 0.8), (t4, 0.0)) * a
    knee = k.keys((t0, 0.0), (t1, 1.0), (t2, 0.08), (t3, 1.0), (t4, 0.0)) * a
    k.lr("femur_y", -15.0 * hip, -85.0 * hip)
    k.lr("tibia_y", 20.0 * hip, 100.0 * knee)
    k.lr("foot_y", 0.0, 25.0 * hip)                        # pointed foot
    k.lean(pitch=-14.0 * hip)                              # lean back to counter the raised leg
    k.spine("y", -6.0 * hip)
    k.neck("y", 12.0 * hip)
    k.lean(roll=5.0 * hip)
    k.lr("femur_x", -4.0 * hip, 0.0)
    k.both("humerus_y", -35.0 * guard)
    k.both("humerus_x", 18.0 * guard)
    k.both("radius_y", -15.0 - 100.0 * guard)
    k.lr("humerus_y", 0.0, 30.0 * hip)                     # right arm drops back as the leg kicks
    k.flat_feet(1.0, 1.0 - hip / max(a, 1e-9))
    return k.plan()


def _guard_stance(k: Take, guard: np.ndarray) -> None:
    """Fighting stance shared by punch and throw: left foot forward, knees soft, hands up."""
    k.lr("femur_y", -14.0 * guard, 8.0 * guard)
    k.both("tibia_y", 16.0 * guard)
    k.both("humerus_y", -40.0 * guard)
    k.both("humerus_x", 15.0 * guard)
    k.both("radius_y", -20.0 - 95.0 * guard)


@primitive("punch")
def punch(k: Take) -> Plan:
    """Right straight punch from a guard: trunk twist drives the right arm straight forward."""
    a = k.amp
    t0 = k.span(0.2, 0.7)
    t1 = t0 + k.span(0.35, 0.45)                           # guard up
    t2 = t1 + k.span(0.13, 0.18)                           # arm extended
    t3 = t2 + k.span(0.1, 0.2)
    t4 = t3 + k.span(0.25, 0.35)                           # back to guard
    t5 = t4 + k.span(0.35, 0.45)                           # hands down
    k.begin(t5 + k.span(0.2, 0.7))
    guard = k.keys((t0, 0.0), (t1, 1.0), (t4, 1.0), (t5, 0.0))
    p = k.keys((t1, 0.0), (t2, 1.0), (t3, 1.0), (t4, 0.0)) * a
    # Some load the punch: a short pull back of the arm and trunk before it goes.
    load = k.keys((t1 - k.scaled(0.25), 0.0), (t1, 1.0), (t2, 0.0)) * k.rng.uniform(0.0, 1.0)
    k.lr("humerus_y", 0.0, 25.0 * load)
    k.spine("z", -15.0 * load)
    _guard_stance(k, guard)
    k.lr("humerus_y", 0.0, k.rng.uniform(-60.0, -30.0) * p)   # body shot to head height
    k.lr("humerus_x", 0.0, -8.0 * p)
    k.lr("radius_y", 0.0, 110.0 * p)
    k.lr("clavicle_z", 0.0, 15.0 * p)                      # shoulder reaches forward
    k.spine("z", 24.0 * p)                                 # right shoulder forward
    k.neck("z", -18.0 * p)                                 # eyes stay on the target
    k.yaw += 10.0 * p
    k.lean(pitch=4.0 * guard + 4.0 * p)
    k.lr("humerus_y", 10.0 * p, 0.0)                       # left hand pulls back
    k.flat_feet(1.0)
    return k.plan()


@primitive("throw")
def throw(k: Take) -> Plan:
    """Right overhand throw: wind up (arm back and up, trunk turned away), whip forward, follow through."""
    a = k.amp
    t0 = k.span(0.2, 0.7)
    t1 = t0 + k.span(0.55, 0.7)                            # wound up
    t2 = t1 + k.span(0.15, 0.2)                            # release
    t3 = t2 + k.span(0.25, 0.35)                           # follow-through
    t4 = t3 + k.span(0.6, 0.8)                             # back to rest
    k.begin(t4 + k.span(0.2, 0.7))
    stance = k.keys((t0, 0.0), (t1, 1.0), (t3, 1.0), (t4, 0.0))
    wind = k.keys((t0, 0.0), (t1, 1.0), (t2, 0.0)) * a
    rel = k.keys((t1, 0.0), (t2, 1.0), (t3, 0.7), (t4, 0.0)) * a
    _guard_stance(k, 0.6 * stance)
    slot = k.rng.uniform(0.65, 1.1)                        # three-quarter to over the top
    k.lr("humerus_x", 0.0, 90.0 * slot * wind + 20.0 * rel)
    k.lr("humerus_z", 0.0, 80.0 * slot * wind)             # forearm up behind the head
    k.lr("humerus_y", -30.0 * wind, 25.0 * wind - 75.0 * rel)
    k.lr("radius_y", 0.0, -20.0 * wind + 70.0 * rel)
    k.spine("z", -30.0 * wind + 30.0 * rel)
    k.spine("y", -8.0 * wind + 22.0 * rel)
    k.neck("z", 25.0 * wind - 20.0 * rel)
    k.neck("y", -10.0 * rel)
    k.yaw += -12.0 * wind + 10.0 * rel
    k.lean(pitch=8.0 * rel)
    k.flat_feet(1.0)
    return k.plan()


@primitive("wave", cyclic=True)
def wave(k: Take) -> Plan:
    """Right-hand greeting: raise the arm to the side with the forearm up, wag it about two times."""
    a = k.amp
    t0 = k.span(0.3, 0.5)
    t1 = t0 + k.span(0.45, 0.6)                            # arm up
    period = k.period(0.5, 0.65)
    cycles = k.cycles(1.8, 2.1)
    t2 = t1 + cycles * period
    t3 = t2 + k.span(0.5, 0.65)
    t = k.begin(t3 + k.span(0.2, 0.35))
    up = k.keys((t0, 0.0), (t1, 1.0), (t2, 1.0), (t3, 0.0))
    wag = np.sin(TAU * (t - t1) / period) * k.keys((t1 - 0.1, 0.0), (t1 + 0.1, 1.0), (t2 - 0.1, 1.0), (t2, 0.0))
    k.lr("humerus_x", 0.0, 85.0 * up + 12.0 * a * wag)
    k.lr("humerus_z", 0.0, 85.0 * up)
    k.lr("humerus_y", 0.0, -15.0 * up)
    k.lr("radius_y", 0.0, -90.0 * up + 30.0 * a * wag)
    k.lr("hand_x", 0.0, 15.0 * a * wag)
    k.lr("clavicle_x", 0.0, 12.0 * up)                     # shoulder shrugs up with the raised arm
    k.spine("x", 6.0 * up)                                 # trunk leans away from the raised arm
    k.neck("x", -4.0 * up + 3.0 * a * wag)
    k.neck("z", -12.0 * up)                                # smile at whoever is waved at
    k.lean(roll=2.0 * up)
    k.flat_feet(1.0)
    return k.plan()


@primitive("jumping_jack", cyclic=True)
def jumping_jack(k: Take) -> Plan:
    """Hop the feet apart while the arms sweep overhead, hop back; about two cycles."""
    a = k.amp
    period = k.period(0.95, 1.1)
    cycles = k.cycles(1.9, 2.1)
    t = k.begin(cycles * period)
    phase = TAU * t / period + k.rng.uniform(0.0, TAU)
    arms = 0.5 * (1.0 - np.cos(phase))                     # 0 at the sides, 1 overhead
    # Legs switch between together and apart during the hops, at phase pi/2 and 3 pi/2 (airborne 0.5 rad
    # either side): a steep smooth step of -cos(phase).
    legs = 0.5 * (1.0 - np.tanh(2.5 * np.cos(phase)) / np.tanh(2.5))
    k.flight[:] = np.abs(np.cos(phase)) < np.sin(0.5)
    landing = np.maximum(bump(2.0 * phase, np.pi + 0.8, 4.0), bump(2.0 * phase, np.pi - 0.8, 4.0))
    # Arms raised in a plane from the frontal (plane 0: straight out to the sides and overhead) to the
    # scapular plane (plane 1: CMU subject 13, humeri flexed 110 deg and abducted 50 deg at the top, elbows
    # bending from 35 to 85 deg).
    plane = k.rng.uniform(0.0, 1.0)
    k.both("humerus_x", a * (160.0 - 110.0 * plane) * arms)
    k.both("humerus_y", -(10.0 + 100.0 * plane) * arms)
    k.both("radius_y", -10.0 - (15.0 + k.rng.uniform(0.0, 40.0) * plane) * arms)
    k.both("femur_x", 16.0 * a * legs)
    k.both("foot_x", -14.0 * a * legs)                     # soles stay flat on spread legs
    k.both("femur_y", -14.0 * landing)
    k.both("tibia_y", 25.0 * landing)
    k.lean(pitch=5.0 * landing)
    k.neck("y", -4.0 * arms)
    k.flat_feet(1.0)
    return k.plan()
