"""Look-alikes of the hook terms on a short straight six-wheel drive (issue 23 audit; a scratch probe, kept).

Run on demand from the repository root::

    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_any_rover_hook_lookalikes.py tether 10
    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_any_rover_hook_lookalikes.py hub 10 5
    OPENBLAS_NUM_THREADS=1 nice python tests/bench/bench_any_rover_hook_lookalikes.py hubLM 10

Records a straight open-loop MER-class drive (3 cm/s, the given seconds) in a world written here:
``tether`` a 30 N pull along the world's -x; ``hub CLEARANCE_MM`` Rankine hub faces (width 0.10 m,
arm 0.05 m) at the six wheels; ``hubLM`` a 3 N m drag on LM's spin. It diagnoses the drive with a
small library (tether: tether_anchor, wheel_radius_all, terrain_slope; hub: hub_contact,
wheel_radius_all, terrain_slope, tether; hubLM: wheel_radius_all with the empirical search), then
prints the verdict, each candidate's score, and the residual chi-square of the believed model with
a 30 N far-anchor tether and (hub) with the concealed hub terms. Writes nothing but a temporary recording.
"""
import math, sys, resource, tempfile
from dataclasses import replace
from pathlib import Path
import numpy as np
ROOT = Path(__file__).resolve().parents[2]
from offline.discrepancy.drive.candidates import DRIVE_CANDIDATES
from offline.discrepancy.drive.diagnosis import diagnose_drives
from offline.discrepancy.drive.synthetic import REALISTIC_SENSORS, DriveSegment, record_drive
from offline.discrepancy.drive.wheel_set import library_for
from offline.rover.scenario import load_scenario
from offline.sim.simulator import DisturbanceForces
MER = load_scenario(ROOT / "offline" / "scenarios" / "rovers" / "mer_nominal.toml")
MINI = load_scenario(ROOT / "offline" / "scenarios" / "nominal.toml")
scale = (MER.rover_file.weight * MER.params.wheel.radius) / (MINI.rover.weight * MINI.params.wheel.radius)
SENS = replace(REALISTIC_SENSORS, torque_noise=REALISTIC_SENSORS.torque_noise * scale)
SPEED=0.03
case = sys.argv[1]; dur=float(sys.argv[2])
seg=(DriveSegment(0.0, dur, (SPEED,) * 6, (0.0,) * 6, "straight"),)
def cpu():
    a=resource.getrusage(resource.RUSAGE_SELF); return a.ru_utime+a.ru_stime
if case=="tether":
    T=30.0
    def hook(t, s):
        # anchor far behind the start: a pull along the world -x, turned into the body frame
        c, sn = math.cos(s.heading), math.sin(s.heading)
        return DisturbanceForces(body_force=(-T*c, T*sn))
    keys=("tether_anchor","wheel_radius_all","terrain_slope")
elif case=="hub":
    # Rankine passive pressure on a face of width b below a clearance, written here (not the library's)
    soil = MER.params.soil
    Kp = math.tan(math.pi/4 + soil.friction_angle/2)**2
    hc, b, arm = float(sys.argv[3])*1e-3, 0.10, 0.05
    xy = [(w.position[0], w.position[1]) for w in MER.rover_file.wheels]
    def hook(t, s):
        wf, tq = [], []
        for i, (x, y) in enumerate(xy):
            e = max(s.sinkage[i] - hc, 0.0)
            F = b*(soil.unit_weight*Kp*e*e/2 + 2*soil.cohesion*math.sqrt(Kp)*e)
            vx, vy = s.u - s.yaw_rate*y, s.v + s.yaw_rate*x
            n = math.sqrt(vx*vx+vy*vy+1e-6)
            wf.append((-F*vx/n, -F*vy/n)); om=s.omega[i]; tq.append(F*arm*om/math.sqrt(om*om+1e-4))
        return DisturbanceForces(wheel_force=tuple(wf), wheel_torque=tuple(tq))
    keys=("hub_contact","wheel_radius_all","terrain_slope", "tether")
elif case=="hubLM":
    i = MER.wheels.index("LM")
    def hook(t, s):
        om = s.omega[i]
        tq=[0.0]*6; tq[i]=3.0*om/math.sqrt(om*om+0.01**2)
        return DisturbanceForces(wheel_force=((0.0,0.0),)*6, wheel_torque=tuple(tq))
    keys=("wheel_radius_all",)
p=record_drive(Path(tempfile.mkdtemp()) / f"{case}.mcap", MER, seed=4, duration=dur, sensors=SENS, segments=seg, disturbance=hook)
c0=cpu()
from offline.sim.simulator import RoverSimulator
from rtctl.messages import Commands
sim=RoverSimulator(MER, seed=1, disturbance=hook); sim.start(Commands(0.0,0,(SPEED,)*6,(0.0,)*6)); sim.advance(2.0); ts=sim.truth_state()
print("sinkage mm", [round(1e3*x,2) for x in ts.sinkage], "dist", ts.disturbance)
lib=[c for c in library_for(DRIVE_CANDIDATES, MER) if c.key in keys]
v=diagnose_drives([p], MER, segment=5, candidates=lib, recalibrate=False, empirical=(case=="hubLM"), seed=4, progress=print)
print(v.summary())
if v.empirical is not None:
    print("\n".join(v.empirical.summary_lines()))
print("CPU", cpu()-c0, "sims", v.model.simulations)
for s in v.scores:
    print(s.label, s.parameters_text(), s.chi2_cv, s.delta_cv)
from offline.discrepancy.drive.candidates import RoverExtension
obs=v.observations; m=v.model
exts = [RoverExtension(terms={"anchor_tension": T, "anchor_bearing": math.pi, "anchor_inverse_distance": 0.0}) for T in (0.0, 30.0)]
if case=="hub":
    exts += [RoverExtension(terms={"hub_clearance": hc, "hub_face_width": b, "hub_arm": arm})]
for ext in exts:
    pred, ok = m.predict(obs, ext)
    z = np.concatenate([((obs.measured[ch]-pred[ch])/obs.noise[ch]) for ch in obs.channels])
    print(ext.terms, ok.all(), "chi2", float(np.nansum(z**2)), {ch: float(np.nanmean((obs.measured[ch]-pred[ch])/obs.noise[ch])) for ch in ("torque_RF","torque_LR","dx_body")})
