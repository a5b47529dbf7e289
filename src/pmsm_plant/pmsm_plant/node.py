"""The ``pmsm_plant`` node: the plant core over topics, in lock-step on sim time.

Publishes sample k (`currents`, `rotor_state`, `/clock` unless another node does), waits for
`voltage_command` stamped k, then advances to k+1. A command with another stamp is discarded and
counted; if no valid command comes within ``lockstep_timeout_s`` the plant applies zero voltage for that
period and names the silent topic.
`angle_error` is published for each `rotor_estimate` that matches a recent sample.

With ``load_torque_per_sample`` (a scenario driver acting as the dyno) the plant takes exactly one
`load_torque` message per sample and starts sample k only once it has the k-th; the shaft speed of
imposed-speed scenarios is the latest `speed_command` at that moment. Otherwise the latest load applies.

A scenario's holding brake keeps the shaft at rest until its lift time after the estimator first
reports tracking: until that report the plant advances sample k only once it has `estimator_state`(k)
too, so the release falls on the same sample as in one process.
"""
import sys
import time
from collections import deque

from geometry_msgs.msg import Vector3Stamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from control_math.frames import wrap
from drive_interface.node import finite, run_node, stamp, topic_qos
from drive_interface.stamps import sample_of, stamp_ns
from drive_interface.topics import TOPICS
from drive_scenarios.node import ScenarioNode

from .build import plant_for_scenario
from .model import OMEGA_M, THETA_M, plant_advance, plant_outputs, sense_currents

HISTORY_SAMPLES = 8


class PlantNode(ScenarioNode):
    def __init__(self, **kwargs):
        super().__init__("pmsm_plant", **kwargs)
        self.declare_parameter("load_torque_per_sample", False)
        self.declare_parameter("angle_error_decimation", 1)
        self.offer_clock()
        self.load_per_sample = self.get_parameter("load_torque_per_sample").value
        self.angle_error_decimation = max(1, int(self.get_parameter("angle_error_decimation").value))
        self.currents_pub = self.create_publisher(Vector3Stamped, "currents", topic_qos("currents"))
        self.rotor_state_pub = self.create_publisher(JointState, "rotor_state", topic_qos("rotor_state"))
        self.clock_pub = None
        self.angle_error_pub = self.create_publisher(Vector3Stamped, "angle_error", topic_qos("angle_error"))
        self.voltage_sub = self.create_subscription(Vector3Stamped, "voltage_command",
                                                    self.timed(self.on_voltage_command),
                                                    topic_qos("voltage_command"))
        self.create_subscription(JointState, "rotor_estimate", self.on_rotor_estimate,
                                 topic_qos("rotor_estimate"))
        self.create_subscription(Float64, "load_torque", self.on_load_torque, topic_qos("load_torque"))
        self.create_subscription(Float64, "speed_command", self.on_speed_command, topic_qos("speed_command"))
        self.braked = bool(self.configured and self.scenario.brake)
        """Waiting for the estimator's first tracking sample (the brake's lift time starts there)."""
        self.brake_release_k = None
        self.brake_states = {}
        self.pending_command = None
        self.state_sub = None
        if self.braked:
            self.state_sub = self.create_subscription(Vector3Stamped, "estimator_state", self.on_estimator_state,
                                                      topic_qos("estimator_state"))
        self.k = 0
        self.tau_load = 0.0
        self.loads = deque()
        self.omega_imposed = 0.0
        self.latest_speed = 0.0
        self.started = False
        self.finished = False
        self.waiting_for_load = False
        self.sent_at = 0.0
        self.history = {}
        self.estimate_seen = -1
        self.zero_voltage_periods = 0
        self.currents_msg = Vector3Stamped()
        self.currents_msg.header.frame_id = TOPICS["currents"].frame_id
        self.rotor_state_msg = JointState(name=["rotor"])
        self.error_msg = Vector3Stamped()
        self.clock_msg = Clock()
        if self.configured:
            s, p = self.scenario, self.plant
            self.n_samples = s.n_samples
            self.publish_config({"scenario": s.name, "T_s_s": s.T_s, "samples": s.n_samples,
                                 "mode": s.mode, "machine": p.machine, "mechanics": p.mechanics,
                                 "inverter": p.inverter, "sensor": p.sensor, "non_idealities": s.non_idealities})
            self.create_timer(min(self.timeout_s / 4.0, 0.05), self.watchdog)
            self.watch_foreign_publishers(("voltage_command",))
        else:
            self.publish_config({})

    def build(self, scenario):
        self.plant = plant_for_scenario(scenario)

    def warm_up(self):
        p = self.plant
        x = p.x.copy()
        i_a, i_b, i_c, _ = plant_outputs(x, p.machine)
        sense_currents(i_a, i_b, i_c, p.sensor, p.seed, 0)
        plant_advance(x, 0.0, 0.0, 0.0, p.imposed_speed, 0.0, p.machine, p.mechanics, p.inverter, p.T_s,
                      p.substeps)
        wrap(0.0)

    def on_load_torque(self, msg):
        if not finite(msg.data):
            self.fault("bad_input", f"load_torque: {msg.data} is not a finite torque; ignored")
            return
        if self.load_per_sample:
            self.loads.append(msg.data)
            if self.started and self.waiting_for_load:
                self.publish_sample()
        else:
            self.tau_load = msg.data

    def on_speed_command(self, msg):
        if finite(msg.data):
            self.latest_speed = msg.data

    def ready(self):
        """Every lock-step partner is matched: `currents` reaches every subscriber the graph shows (at
        least estimator and controller; a graph entry is not yet a match), a `voltage_command` publisher
        is matched, `estimator_state` too while a brake holds, and the first load is in when taken per
        sample. With the shaft held (commissioning) one partner answers currents with voltages and no
        estimator runs."""
        matched = self.currents_pub.get_subscription_count()
        held = self.parameters["shaft_held"]
        return (matched >= max(1 if held else 2, self.count_subscribers("currents"))
                and self.voltage_sub.get_publisher_count() >= 1
                and (held or self.count_publishers("rotor_estimate") >= 1)
                and (self.state_sub is None or self.state_sub.get_publisher_count() >= 1)
                and (self.loads or not self.load_per_sample))

    def watchdog(self):
        if self.finished:
            return
        if not self.started:
            if self.ready():
                self.started = True
                self.clock_pub = self.claim_clock()
                self.publish_sample()
            return
        if time.monotonic() - self.sent_at <= self.timeout_s:
            return
        if self.waiting_for_load:
            self.fault("timeout", f"sample {self.k}: no {self.resolve_topic_name('load_torque')} within "
                                  f"{self.timeout_s:g} s; the last load is kept")
            self.loads.append(self.tau_load)
            self.publish_sample()
        else:
            estimating = not self.parameters["shaft_held"] and self.estimate_seen < self.k
            silent = "rotor_estimate" if estimating else "voltage_command"
            self.fault("timeout", f"sample {self.k}: no answer within {self.timeout_s:g} s "
                                  f"(silent topic: {self.resolve_topic_name(silent)}); zero voltage applied")
            self.advance(0.0, 0.0, safe_state=True)

    def publish_sample(self):
        p, k = self.plant, self.k
        if self.load_per_sample:
            self.waiting_for_load = not self.loads
            if self.waiting_for_load:
                return
            self.tau_load = self.loads.popleft()
        self.omega_imposed = self.latest_speed
        x = p.x
        i_a, i_b, i_c, tau_e = plant_outputs(x, p.machine)
        m_a, m_b, m_c = sense_currents(i_a, i_b, i_c, p.sensor, p.seed, k)
        self.history[k] = (x[THETA_M], x[OMEGA_M])
        self.history.pop(k - HISTORY_SAMPLES, None)
        t = stamp(k, self.T_s)
        if self.clock_pub:
            self.clock_msg.clock = t
            self.clock_pub.publish(self.clock_msg)
        r = self.rotor_state_msg
        r.header.stamp = t
        r.position = [x[THETA_M]]
        r.velocity = [x[OMEGA_M]]
        r.effort = [tau_e]
        m = self.currents_msg
        m.header.stamp = t
        m.vector.x, m.vector.y, m.vector.z = m_a, m_b, m_c
        self.sent_at = time.monotonic()
        self.rotor_state_pub.publish(r)
        self.currents_pub.publish(m)

    def on_voltage_command(self, msg):
        if not self.started or self.finished:
            return
        k = sample_of(msg.header, self.T_s)
        if k != self.k:
            t = msg.header.stamp
            self.fault("wrong_stamp", f"voltage_command stamped {t.sec}.{t.nanosec:09d} while waiting for "
                                      f"sample {self.k} ({stamp_ns(self.k, self.T_s)} ns); discarded")
            return
        u = msg.vector
        limit = self.plant.inverter.U_dc_V
        if not finite(u.x, u.y) or abs(u.x) > limit or abs(u.y) > limit:
            self.fault("bad_input", f"voltage_command at sample {k}: ({u.x}, {u.y}) V is not a voltage the "
                                    f"inverter can apply; zero voltage applied")
            self.advance(0.0, 0.0, safe_state=True)
            return
        if self.braked and k not in self.brake_states:
            self.pending_command = (u.x, u.y)
            return
        self.advance(u.x, u.y)

    def on_estimator_state(self, msg):
        """While the brake holds: the estimator's state of a sample (3 releases it)."""
        k = sample_of(msg.header, self.T_s)
        if not self.braked or k is None or k < self.k:
            return
        self.brake_states[k] = msg.vector.z
        if self.pending_command is not None and self.k in self.brake_states:
            self.advance(*self.pending_command)

    def advance(self, u_alpha, u_beta, safe_state=False):
        """Apply the command of sample k (zero voltage as the safe state after a fault) and go to k+1."""
        p = self.plant
        self.zero_voltage_periods += safe_state
        self.pending_command = None
        if self.braked and self.brake_states.pop(self.k, None) == 3.0:
            self.braked = False
            self.brake_states.clear()
            self.brake_release_k = self.k + round(self.scenario.brake_release_s / self.T_s)
        held = self.braked or (self.brake_release_k is not None and self.k < self.brake_release_k)
        plant_advance(p.x, u_alpha, u_beta, self.tau_load, p.imposed_speed or held,
                      0.0 if held else self.omega_imposed, p.machine, p.mechanics, p.inverter, p.T_s, p.substeps)
        self.sample_handled(self.k)
        self.k += 1
        if self.k >= self.n_samples:
            self.finished = True
            return
        self.publish_sample()

    def on_rotor_estimate(self, msg):
        k = sample_of(msg.header, self.T_s)
        if k is None or k not in self.history:
            return
        self.estimate_seen = max(self.estimate_seen, k)
        if k % self.angle_error_decimation or not finite(*msg.position, *msg.velocity):
            return
        theta_m, omega_m = self.history[k]
        n_p = self.plant.machine.n_p
        e = self.error_msg
        e.header.stamp = msg.header.stamp
        e.vector.x = wrap(n_p * (theta_m - msg.position[0]))
        e.vector.y = omega_m - msg.velocity[0]
        self.angle_error_pub.publish(e)

    def status_values(self):
        return {"sample": self.k, "started": self.started, "finished": self.finished,
                "sim_time_s": self.k * self.T_s, "safe_state_periods": self.zero_voltage_periods}


def main(argv=None):
    """``plant_node [--executor events|single] --ros-args ...`` (``ros2 run pmsm_plant plant_node``)."""
    return run_node(PlantNode, "plant_node", argv)


if __name__ == "__main__":
    sys.exit(main())
