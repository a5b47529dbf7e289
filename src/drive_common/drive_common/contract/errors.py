"""The base of the drive's domain errors: each says in one line what is wrong and where it came from
(file, key, topic, parameter); the command line prints it, a node latches it as a fault."""


class DriveError(ValueError):
    """A request the drive cannot carry out, worded as a domain fact."""
