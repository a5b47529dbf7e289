"""What composes the cores (no node of its own): the one-process runner (``runner``), the ROS graph's
launcher (``launch``), recordings (``bags``), evaluation and benchmarks (``evaluation``) and the ``drive``
command line (``cli``)."""
