"""The ``foc_controller`` node: the cascade controller core over topics.

For sample k it joins `currents`, `rotor_estimate` and `injection` stamped k, runs the core with the
latest `speed_command`, and answers `voltage_command`(k). The robot-facing `joint_states` (estimated
position, speed, torque) is published every ``joint_states_decimation`` samples. Bad currents or
estimates, or a rejected speed limit, give zero voltage and a reported fault; the node keeps answering.
"""
import math

from geometry_msgs.msg import Vector3Stamped
from pmsm_plant.contract import (COMMAND_QOS, PER_SAMPLE_QOS, RESYNC_SAMPLES, DriveNode, finite, sample_of,
                                 stamp)
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from .control import OMEGA_FILTERED, controller_step, estimated_torque
from .params import check_speed_limit

SPEED_LIMIT = "controller.speed_limit_rad_s"


class ControllerNode(DriveNode):
    def __init__(self, builder, **kwargs):
        super().__init__("foc_controller", builder, **kwargs)
        self.declare_parameter("joint_states_decimation", 100)
        self.decimation = max(1, int(self.get_parameter("joint_states_decimation").value))
        self.joint_pub = self.create_publisher(JointState, "joint_states", COMMAND_QOS)
        inputs = [self.create_subscription(Vector3Stamped, "currents", self.timed(self.on_currents),
                                           PER_SAMPLE_QOS),
                  self.create_subscription(JointState, "rotor_estimate", self.on_estimate, PER_SAMPLE_QOS),
                  self.create_subscription(Vector3Stamped, "injection", self.on_injection, PER_SAMPLE_QOS)]
        self.open_when_matched(inputs, self.open_outputs)
        self.create_subscription(Float64, "speed_command", self.on_speed_command, COMMAND_QOS)
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.currents, self.estimates, self.injections = {}, {}, {}
        self.k = 0
        self.omega_m_ref = 0.0
        self.current_limited = False
        self.voltage_msg = Vector3Stamped()
        self.voltage_msg.header.frame_id = "alpha_beta"
        self.joint_msg = JointState(name=["rotor"])
        if self.drive:
            self.params = self.drive.controller
            self.n_p = self.params.n_p
            self.trip_A = self.trip_current_A()
            self.publish_config({"controller": self.params})
        else:
            self.publish_config({})

    def warm_up(self):
        d = self.drive
        controller_step(d.controller_x.copy(), d.controller_z.copy(), d.controller, 0.0, 0.0, 0.0, 0.0, 0.0,
                        0.0, 0.0, 0.0)

    def open_outputs(self):
        self.voltage_pub = self.create_publisher(Vector3Stamped, "voltage_command", PER_SAMPLE_QOS)

    def on_set_parameters(self, parameters):
        for p in parameters:
            if p.name != SPEED_LIMIT:
                continue
            try:
                check_speed_limit(p.value)
            except ValueError as error:
                self.health.latched = f"parameter {SPEED_LIMIT} rejected ({error}); zero voltage until a " \
                                      f"valid limit is set"
                self.fault("parameter", self.health.latched)
                return SetParametersResult(successful=False, reason=str(error))
            if self.drive:
                self.params = self.params._replace(speed_limit_rad_s=float(p.value))
            if self.health.latched and SPEED_LIMIT in self.health.latched:
                self.health.latched = None
        return SetParametersResult(successful=True)

    def on_speed_command(self, msg):
        if finite(msg.data):
            self.omega_m_ref = msg.data
        else:
            self.fault("bad_input", f"speed_command: {msg.data} is not a finite speed; ignored")

    def on_currents(self, msg):
        self.store(self.currents, msg, (msg.vector.x, msg.vector.y, msg.vector.z))

    def on_estimate(self, msg):
        value = (msg.position[0], msg.velocity[0]) if msg.position and msg.velocity else (math.nan, math.nan)
        self.store(self.estimates, msg, value)

    def on_injection(self, msg):
        self.store(self.injections, msg, (msg.vector.x, msg.vector.y))

    def store(self, table, msg, value):
        k = sample_of(msg.header, self.T_s)
        if k is None or not self.k <= k <= self.k + RESYNC_SAMPLES:
            self.fault("wrong_stamp", f"stamp {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d} is not a "
                                      f"sample in {self.k}..{self.k + RESYNC_SAMPLES}; discarded")
            return
        table[k] = value
        if table is self.currents and k > self.k:
            self.resynchronise(k)
        k = self.k
        while k in self.currents and k in self.estimates and k in self.injections:
            self.step(k, self.currents.pop(k), self.estimates.pop(k), self.injections.pop(k))
            k = self.k = k + 1

    def resynchronise(self, k):
        """Currents of a later sample mean the plant gave up on samples self.k..k−1 (they never completed
        here: an input was lost, e.g. sent before a subscription matched); follow it to k."""
        self.fault("missed_sample", f"samples {self.k}..{k - 1} never completed (currents, rotor_estimate or "
                                    f"injection missing); following the plant to sample {k}")
        for table in (self.currents, self.estimates, self.injections):
            for old in [j for j in table if j < k]:
                del table[old]
        self.k = k

    def step(self, k, currents, estimate, injection):
        u_alpha = u_beta = 0.0
        if not self.drive or self.health.latched:
            pass
        elif not finite(*currents) or max(map(abs, currents)) > self.trip_A:
            self.fault("bad_input", f"currents at sample {k}: {currents} A are not finite or beyond the "
                                    f"{self.trip_A:g} A trip; zero voltage")
        elif not finite(*estimate, *injection):
            self.fault("bad_input", f"rotor_estimate/injection at sample {k} not finite; zero voltage")
        else:
            d = self.drive
            u_alpha, u_beta, i_d, i_q, _, i_q_ref = controller_step(
                d.controller_x, d.controller_z, self.params, *currents, self.n_p * estimate[0],
                self.n_p * estimate[1], self.omega_m_ref, *injection)
            self.current_limited = abs(i_q_ref) >= self.params.i_max_A
            if k % self.decimation == 0:
                j = self.joint_msg
                j.header.stamp = stamp(k, self.T_s)
                j.position = [estimate[0]]
                j.velocity = [d.controller_x[OMEGA_FILTERED] / self.n_p]
                j.effort = [estimated_torque(self.params, i_d, i_q)]
                self.joint_pub.publish(j)
        m = self.voltage_msg
        m.header.stamp = stamp(k, self.T_s)
        m.vector.x, m.vector.y = u_alpha, u_beta
        self.voltage_pub.publish(m)

    def status_values(self):
        return {"sample": self.k, "speed_command_rad_s": self.omega_m_ref,
                "current_limited": self.current_limited}
