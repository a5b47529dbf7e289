"""The ``drive_commissioning`` node: the commissioning procedure core over topics, in the controller's
place. For sample k it takes `currents`(k) and answers `voltage_command`(k) until the procedure ends;
the plant (or the drive_bridge node with a real inverter) must run with the shaft held (its parameter
``shaft_held``; a real robot: the brake engaged) for ``duration_s`` = the procedure's length
(``procedure.procedure_for_scenario(...).total_samples``). At the end it writes the record to the
parameter ``out`` (when given) and says ``run_complete`` on /diagnostics. Bad currents, or a test current the
bus does not drive (procedure.CommissioningError), abort the procedure: zero voltage from then on.
"""
import sys

from geometry_msgs.msg import Vector3Stamped

from drive_common.contract.stamps import sample_of
from drive_common.contract.topics import CURRENTS, TOPICS, VOLTAGE_COMMAND
from drive_common.motor.commissioning import save_commissioning
from drive_common.ros.node import DriveNode, finite, run_node, stamp, topic_qos

from .procedure import METHOD, CommissioningError, procedure_for_scenario


class CommissioningNode(DriveNode):
    node_parameters = {"out": ("", "commissioning file to write at the end (empty: none)")}

    def __init__(self, **kwargs):
        super().__init__("drive_commissioning", **kwargs)
        self.k = 0
        self.first = None
        """The stamp's sample number of the first currents: a real inverter's count need not start at 0."""
        self.aborted = None
        self.written = None
        self.voltage_msg = Vector3Stamped()
        self.voltage_msg.header.frame_id = TOPICS[VOLTAGE_COMMAND].frame_id
        self.voltage_pub = None
        if not self.configured:
            self.publish_config({})
            return
        self.trip_A = self.trip_current_A()
        currents = self.create_subscription(Vector3Stamped, CURRENTS, self.timed(self.on_currents),
                                            topic_qos(CURRENTS))
        self.open_when_matched([currents], self.open_outputs)
        self.watch_peer(CURRENTS, "the plant")
        self.publish_config({"procedure": METHOD, "samples": self.procedure.total_samples})

    def build(self, scenario):
        self.procedure = procedure_for_scenario(scenario)

    def open_outputs(self):
        self.voltage_pub = self.create_publisher(Vector3Stamped, VOLTAGE_COMMAND, topic_qos(VOLTAGE_COMMAND))

    def on_currents(self, msg):
        k = sample_of(msg.header, self.T_s)
        if k is None or (self.first is not None and k < self.first + self.k):
            self.fault("wrong_stamp", f"currents stamped {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d} "
                                      f"are not a sample after the last; discarded")
            return
        if self.first is None:
            self.first = k
        v = msg.vector
        u_alpha = u_beta = 0.0
        p = self.procedure
        if self.aborted or p.done:
            pass
        elif k != self.first + self.k:
            self.abort(f"samples {self.first + self.k}..{k - 1} never arrived; the procedure needs every "
                       f"sample: commissioning aborted, zero voltage", "missed_sample")
        elif not finite(v.x, v.y, v.z) or max(abs(v.x), abs(v.y), abs(v.z)) > self.trip_A:
            self.abort(f"currents at sample {k}: ({v.x}, {v.y}, {v.z}) A are not finite or beyond the "
                       f"{self.trip_A:g} A trip; commissioning aborted, zero voltage", "bad_input")
        else:
            try:
                u_alpha, u_beta = p.step(self.k, v.x, v.y, v.z)
            except CommissioningError as error:
                self.abort(f"{error}; zero voltage", "refused")
            if p.done:
                self.finish()
        m = self.voltage_msg
        m.header.stamp = stamp(k, self.T_s)
        m.vector.x, m.vector.y = u_alpha, u_beta
        self.voltage_pub.publish(m)
        self.k = k + 1 - self.first

    def abort(self, message, kind):
        self.aborted = message
        self.health.latched = message
        self.fault(kind, message)

    def finish(self):
        out = self.get_parameter("out").value
        if out:
            self.written = str(save_commissioning(out, self.procedure.result(), self.config.motor.name, METHOD,
                                                  self.procedure.conditions()))
        self.complete_run()

    def status_values(self):
        return {"sample": self.k, "done": bool(self.configured and self.procedure.done),
                "aborted": bool(self.aborted)}


def main(argv=None):
    """``commissioning_node [--executor events|single] --ros-args ...``."""
    return run_node(CommissioningNode, "commissioning_node", argv)


if __name__ == "__main__":
    sys.exit(main())
