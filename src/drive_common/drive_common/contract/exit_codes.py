"""Exit codes of the `drive` command and the node executables (docs/drive-interface.md)."""
import signal

EXIT_OK = 0
EXIT_REFUSED = 2
"""The request was refused (bad input, a file, topic or namespace at fault); one line on stderr says
why."""
EXIT_NODE_FAULTS = 3
"""The run finished, but a node reported a fault during it (node_faults); for a node executable: it
ended because its peer was gone before its run was complete or after faults."""
EXIT_RECORDING_FAILED = 4
"""The run finished and its metrics are printed, but an output could not be written in full: the
recording stopped early (closed as far as written), the plot (an unwritable directory), or samples lost on
their way to the launcher's log and recording (`missing_samples`, no node fault explaining them)."""
EXIT_NOT_TRACKING = 5
"""The run finished, but the drive refused to start (no saliency, no polarity, the rotor moved) or ended holding zero
torque after a lost lock; the metrics say which."""
EXIT_NOT_FOLLOWING = 6
"""The run finished, but the shaft did not follow its command: dragged backwards, stalled, not following,
or at the current limit for longer than the supervision allows (foc_controller.supervision)."""
EXIT_TRIPPED = 7
"""The run finished and its metrics are printed, but the drive's protections tripped it into its safe state
(a DC-link over-voltage; foc_controller.protection): ``protection`` in the report says when and which."""
EXIT_SIGNAL_BASE = 128
"""128 + N: stopped by signal N (130 SIGINT, 143 SIGTERM), with what was done printed, marked
interrupted."""
EXIT_READER_GONE = EXIT_SIGNAL_BASE + signal.SIGPIPE
"""The reader of the output went away (`drive echo ... | head`): output stopped quietly."""
