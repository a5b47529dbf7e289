"""What a perfect commissioning would identify on the simulated plant, with the record's keys: the
truth `drive commission --json` scores its measurement against. Only the composition's scoring calls
this; the drive itself never sees it."""
import math

import numpy as np

from .model import incremental_inductances, saturation_saliency_angle


def saliency_shift_and_slope(machine, i_q_A, d_sweep_A=0.01):
    """(δ [rad], F = 1 + i_q·∂δ/∂i_d) of ``machine`` at (0, i_q_A); δ from d whichever axis has the
    smaller inductance at no load."""
    L_dh, L_qh, _ = incremental_inductances(machine)
    sign = 1.0 if L_dh <= L_qh else -1.0
    shift = saturation_saliency_angle(machine, 0.0, i_q_A, sign)
    slope = 1.0 + i_q_A * (saturation_saliency_angle(machine, d_sweep_A, i_q_A, sign)
                           - saturation_saliency_angle(machine, -d_sweep_A, i_q_A, sign)) / (2.0 * d_sweep_A)
    return shift, slope


def commissioning_truth(plant, rated_current_A):
    """The plant's (pmsm_plant.build.Plant) true values under the commissioning record's keys, and the
    saliency shift and convergence slope at rated current (δ at rated, F at rated)."""
    m, inv, s = plant.machine, plant.inverter, plant.sensor
    L_dh, L_qh, _ = incremental_inductances(m)
    gains = np.array([s.gain_a, s.gain_b, s.gain_c])
    gains = gains / gains.mean()
    shift, slope = saliency_shift_and_slope(m, rated_current_A)
    lsb = 2.0 * s.adc_range_A / (1 << s.adc_bits) if s.adc_bits > 0 else 0.0
    return {"R_s_ohm": m.R_s_ohm, "dead_time_voltage_V": inv.t_dead_s / plant.T_s * inv.U_dc_V,
            "sensor_gain_a": gains[0], "sensor_gain_b": gains[1], "sensor_gain_c": gains[2],
            "sensor_offset_a_A": s.offset_a_A, "sensor_offset_b_A": s.offset_b_A,
            "sensor_offset_c_A": s.offset_c_A, "sensor_noise_A": math.sqrt(s.noise_std_A ** 2 + lsb ** 2 / 12.0),
            "L_dh_H": L_dh, "L_qh_H": L_qh,
            "saliency_shift_at_rated_rad": shift, "convergence_slope_at_rated": slope}
