"""Test doubles, apart from what runs a real drive (as ros2_control keeps its mock components): the virtual
inverter that stands in for a real one behind the protocol (on a thread, or in a process of its own), the
device ends of its virtual links, how the host kept pace with it, and its faulty versions for the tests and
benches that need link faults."""
