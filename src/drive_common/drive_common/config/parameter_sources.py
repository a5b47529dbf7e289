"""Where a node executable's parameters come from (`--ros-args -p NAME:=VALUE` and `--params-file FILE`),
so that an error names its true source, and an unknown key in a params file is refused, not ignored."""
import fnmatch

import yaml

ROS_ARGS = []
"""The ``--ros-args ...`` of the node executable running in this process (empty for composed nodes)."""


class ParameterSourceError(ValueError):
    """A params file cannot be read or is not a mapping of node names."""


def _flatten(values, prefix=""):
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            yield from _flatten(value, f"{name}.")
        else:
            yield name


def _applies(pattern, node_name, namespace):
    """rcl's matching of a params file's node key: ``/**``, ``name``, ``/ns/name``, wildcards."""
    full = f"{namespace.rstrip('/')}/{node_name}"
    pattern = pattern if pattern.startswith("/") else f"/{pattern}"
    return pattern == "/**" or fnmatch.fnmatchcase(full, pattern.replace("/**/", "/*"))


def command_line_sources(ros_args, node_name=None, namespace="/"):
    """{parameter: "params file PATH" | "command line -p NAME"} for the node ``namespace/node_name``
    (every node's entries when None) from its ``--ros-args ...``; ParameterSourceError when a params
    file is unreadable."""
    sources = {}
    for i, arg in enumerate(ros_args[:-1]):
        following = ros_args[i + 1]
        if arg == "--params-file":
            try:
                with open(following, encoding="utf-8") as stream:
                    data = yaml.safe_load(stream) or {}
            except (OSError, UnicodeDecodeError, yaml.YAMLError) as error:
                reason = getattr(error, "strerror", None) or str(error).splitlines()[0]
                raise ParameterSourceError(f"params file {following}: cannot be read ({reason})") from None
            if not isinstance(data, dict):
                raise ParameterSourceError(f"params file {following}: not a mapping of node names")
            for pattern, entry in data.items():
                parameters = (entry or {}).get("ros__parameters") if isinstance(entry, dict) else None
                if isinstance(parameters, dict) and (node_name is None
                                                     or _applies(str(pattern), node_name, namespace)):
                    sources.update(dict.fromkeys(_flatten(parameters), f"params file {following}"))
        elif arg == "-p" and ":=" in following:
            name = following.split(":=", 1)[0]
            sources[name] = f"command line -p {name}"
    return sources


def unknown_parameters(node, sources):
    """One line per parameter given on the command line or in a params file that ``node`` does not
    declare."""
    known = ", ".join(sorted(name for name in node.list_parameters([], 0).names if name != "use_sim_time"))
    return [f"{source}: unknown parameter '{name}' for {node.get_fully_qualified_name()} (known: {known})"
            for name, source in sorted(sources.items()) if not node.has_parameter(name)]


def label(sources, name):
    """How an error names parameter ``name``: "params file F: parameter NAME", "command line -p NAME",
    or "parameter NAME" (given by a launcher or defaulted)."""
    source = sources.get(name, "")
    if source.startswith("params file"):
        return f"{source}: parameter {name}"
    return source or f"parameter {name}"
