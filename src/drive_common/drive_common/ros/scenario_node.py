"""The base of the simulated drive's nodes: a ContractNode configured by a scenario file and the
override parameters (``parameters.NODE_PARAMETERS``)."""
from drive_common.config.parameter_sources import label
from drive_common.config.parameters import NODE_PARAMETERS, scenario_from_parameters
from drive_common.contract.topics import BLOCK_TOPIC
from drive_common.motor.commissioning import resolve_commissioning
from drive_common.motor.nameplate import contract_motor, trip_current_A
from drive_common.ros.node import ContractNode, describe, stamp


class ScenarioNode(ContractNode):
    """Declares NODE_PARAMETERS, loads the scenario they name and calls ``build(scenario)``, the node's
    own core (a ValueError there names the key at fault).

    A configuration error leaves ``self.configured`` False: the node stays up, answers with the safe
    output and reports the error (``self.health.latched``). Otherwise ``warm_up`` compiles the node's
    kernels on copies of its state before any per-sample endpoint exists, so no first sample waits for
    the compiler."""

    node_parameters = {}
    """The node's own parameters beyond NODE_PARAMETERS: name → (default, description)."""

    def needs_experiment(self):
        """With a ``drive_configuration``: whether the node also reads its scenario's experiment (the
        plant does; the estimator does not)."""
        return True

    def __init__(self, node_name, **kwargs):
        super().__init__(node_name, **kwargs)
        for name, (default, text) in {**NODE_PARAMETERS, **self.node_parameters}.items():
            if not self.has_parameter(name):
                self.declare_parameter(name, default, descriptor=describe(text))
        self.parameters = {name: self.get_parameter(name).value for name in NODE_PARAMETERS}
        self.scenario = None
        self.configured = False
        try:
            scenario = scenario_from_parameters(self.parameters, self.label, self.needs_experiment())
            self.build(scenario)
        except ValueError as error:
            self.reject(error)
        else:
            self.scenario = scenario
            self.configured = True
            self.warm_up()
        self.T_s = self.scenario.T_s if self.scenario else 1e-4
        self.timeout_s = float(self.parameters["lockstep_timeout_s"])

    @property
    def block_samples(self):
        """N: samples per message on the per-sample topics (the scenario's block_samples)."""
        return self.scenario.block_samples if self.scenario else 1

    def contract_topics(self, *topics):
        """The per-sample topics as this drive carries them: themselves, or their block twins."""
        return tuple(BLOCK_TOPIC[t] if self.block_samples > 1 else t for t in topics)

    def label(self, name):
        """How errors name parameter ``name`` (its params file, the command line, or the parameter)."""
        return label(self.parameter_sources, name)

    def start_line(self):
        if not self.scenario:
            return f"{super().start_line()}: configuration rejected, output held safe"
        s = self.scenario
        run = "no experiment: until stopped" if s.open_ended else f"{s.n_samples} samples"
        what = f"drive configuration {s.drive_file}" if s.open_ended else f"scenario {s.name}"
        return (f"{super().start_line()}: {what}, motor {s.motor}, estimator {s.estimator}, "
                f"{1.0 / s.T_s:g} Hz, {run}")

    def data_time(self):
        """The stamp of the node's current sample (sim time)."""
        return stamp(getattr(self, "k", 0), self.T_s)

    def sample_handled(self, k):
        """Sample k is done; after the scenario's last one, /diagnostics says the run is complete."""
        if self.scenario and k == self.scenario.n_samples - 1:
            self.complete_run()

    def reject(self, error):
        """Latch a configuration error: the output is held safe and /diagnostics says why."""
        self.health.latched = str(error)
        self.health.fault("configuration", str(error))
        self.get_logger().error(f"configuration rejected, output held safe: {error}")

    def build(self, scenario):
        """Build the node's core for ``scenario``."""

    def warm_up(self):
        """Call the node's kernels once on copies of its state, with the argument types of a sample."""

    def open_when_matched(self, subscriptions, open_outputs, ready=lambda: True):
        """Call ``open_outputs`` (creating the node's per-sample answer publishers) once every input
        subscription is matched to a publisher and ``ready()``. An answer sent before its reader matched
        is lost, and a graph entry is not yet a match: gated so, the answer publishers' appearance tells
        the plant, at the end of the chain, that every node before it can hear its inputs."""
        def check():
            if ready() and all(s.get_publisher_count() >= 1 for s in subscriptions):
                timer.cancel()
                open_outputs()
        timer = self.create_timer(0.02, check)

    def nameplate(self):
        """The nameplate of the scenario's motor."""
        return self.scenario.motor.nameplate

    def load_commissioning(self, scenario):
        """What the drive knows beyond the nameplate (drive_common.motor.commissioning.resolve_commissioning):
        the file of the parameter ``commissioning`` or the scenario's key, the default file, or the
        nameplate alone; CommissioningError names the parameter or scenario key at fault."""
        label = (self.label("commissioning") if self.parameters["commissioning"]
                 else f"{scenario.source}: commissioning")
        return resolve_commissioning(scenario.motor.nameplate, scenario.commissioning, label)

    def publish_config(self, config):
        if self.scenario:
            config = {"motor": contract_motor(self.nameplate()),
                      "scenario": self.scenario.name, "n_p": self.nameplate().n_p, "T_s_s": self.T_s,
                      "block_samples": self.block_samples,
                      "command_delay_periods": self.scenario.drive_delay_periods(), **config}
        super().publish_config(config)

    def trip_current_A(self):
        given = float(self.parameters["trip_current_A"])
        return given if given > 0.0 else trip_current_A(self.nameplate())
