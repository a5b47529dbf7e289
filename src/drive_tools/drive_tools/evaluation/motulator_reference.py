"""motulator's 2.2-kW PMSM signal-injection example (examples/drive/signal_inj, motulator 0.18),
timed. Run by ``drive bench throughput`` with the interpreter that has motulator (a side virtual
environment: motulator needs Python ≥ 3.12); prints one JSON object. Imports nothing of this project.

The system is the example's: 2.2 kW IPMSM, square-wave injection with a PLL, speed steps of ±0.1 p.u.
under rated load, 4 s. Its controller samples at 8 kHz and its plant is integrated by scipy's ODE
solver between samples, so 'samples' are controller periods."""
import json
import time

import motulator.drive.control.sm as control
import numpy as np
from motulator.drive import model, utils


def run_example():
    nom = utils.NominalValues(U=370, I=4.3, f=75, P=2.2e3, tau=14)
    base = utils.BaseValues.from_nominal(nom, n_p=3)
    par = model.SynchronousMachinePars(n_p=3, R_s=3.6, L_d=0.036, L_q=0.051, psi_f=0.545)
    drive = model.Drive(model.SynchronousMachine(par), model.MechanicalSystem(J=0.015),
                        model.VoltageSourceConverter(u_dc=540))
    vector = control.SignalInjectionController(par, control.CurrentVectorControllerCfg(i_s_max=2 * base.i))
    ctrl = control.VectorControlSystem(vector, control.SpeedController(J=0.015, alpha_s=2 * np.pi * 4))
    t_stop = 4.0
    ctrl.set_speed_ref(utils.SequenceGenerator(
        np.array([0, 0.25, 0.25, 0.375, 0.5, 0.625, 0.75, 0.75, 1]) * t_stop,
        np.array([0, 0, 1, 1, 0, -1, -1, 0, 0]) * 0.1 * base.w_M))
    drive.mechanics.set_external_load_torque(utils.SequenceGenerator(
        np.array([0, 0.125, 0.125, 0.875, 0.875, 1]) * t_stop, np.array([0, 0, 1, 1, 0, 0]) * nom.tau))
    simulation = model.Simulation(drive, ctrl, show_progress=False)
    start, start_cpu = time.perf_counter(), time.process_time()
    result = simulation.simulate(t_stop)
    wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    samples = len(result.ctrl.t)
    return {"example": "motulator 2.2-kW PMSM signal injection", "simulated_s": t_stop,
            "samples": samples, "wall_time_s": wall, "samples_per_second": samples / wall,
            "cpu_time_s": cpu, "samples_per_cpu_second": samples / cpu}


if __name__ == "__main__":
    print(json.dumps(run_example()))
