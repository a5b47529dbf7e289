"""The process's run time: signals that stop a run, real-time scheduling and the machine's load."""
