"""Builds the drive's own message package ``drive_msgs`` (drive_msgs/msg/SampleBlock: the block topics, docs/
drive-interface.md "Block transport") into this Python environment, as colcon would for an interface package, from
the rosidl generators of the PyPI ROS wheels: C structures, the C, Fast DDS and introspection type supports and the
Python bindings, compiled with the system's C and C++ compilers; libraries into ``PREFIX/lib`` (on the ROS wheels'
library path), the Python package into site-packages, the interface files and the ament index entries into
``PREFIX/share``. Run by ./setup.sh; does nothing when the installed package was built from the same files.

Usage: ``.venv/bin/python src/drive_common/build_messages.py``."""
import hashlib
import logging
import os
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

PACKAGE, MESSAGE = "drive_msgs", "SampleBlock"
SOURCE = Path(__file__).resolve().parent / "drive_common" / "contract" / "msg"
PREFIX = Path(sys.prefix)
SITE = Path(sysconfig.get_paths()["purelib"])
TYPESUPPORTS = ("c", "fastrtps_c", "introspection_c")
LINKED = {
    "rosidl_generator_c": ["std_msgs__rosidl_generator_c", "builtin_interfaces__rosidl_generator_c",
                           "rosidl_runtime_c", "rcutils"],
    "rosidl_typesupport_fastrtps_c": [f"{PACKAGE}__rosidl_generator_c", "std_msgs__rosidl_typesupport_fastrtps_c",
                                      "builtin_interfaces__rosidl_typesupport_fastrtps_c",
                                      "rosidl_typesupport_fastrtps_c", "rosidl_typesupport_fastrtps_cpp", "fastcdr",
                                      "rosidl_runtime_c", "rcutils"],
    "rosidl_typesupport_introspection_c": [f"{PACKAGE}__rosidl_generator_c",
                                           "std_msgs__rosidl_typesupport_introspection_c", "rosidl_runtime_c"],
    "rosidl_typesupport_c": [f"{PACKAGE}__rosidl_generator_c", "rosidl_typesupport_c", "rosidl_runtime_c", "rcutils"],
    "rosidl_generator_py": [f"{PACKAGE}__rosidl_generator_c", "std_msgs__rosidl_generator_py", "rosidl_runtime_c"],
}
"""Each library of the package and what it links against."""


def fingerprint():
    """What the installed package was built from: the interface files and this script."""
    digest = hashlib.sha256()
    for path in sorted(SOURCE.iterdir()) + [Path(__file__).resolve()]:
        digest.update(path.read_bytes())
    return digest.hexdigest()


def generate(work):
    """The generated sources, one folder per generator under ``work``."""
    from rosidl_generator_c.cli import GenerateC
    from rosidl_generator_py.cli import GeneratePython
    from rosidl_typesupport_c.cli import GenerateCTypesupport
    from rosidl_typesupport_fastrtps_c.cli import GenerateFastRTPSCTypesupport
    from rosidl_typesupport_introspection_c.cli import GenerateIntrospectionCTypesupport
    os.environ.setdefault("AMENT_PREFIX_PATH", str(PREFIX))
    logging.getLogger("rosidl_cli.entry_points").setLevel(logging.ERROR)  # the wheels list some entry points twice
    (work / "src" / "msg").mkdir(parents=True)
    shutil.copy(SOURCE / f"{MESSAGE}.idl", work / "src" / "msg")
    interface = [f"{work / 'src'}:msg/{MESSAGE}.idl"]
    includes = [str(PREFIX / "share")]
    implementations = [f"rosidl_typesupport_{name}" for name in TYPESUPPORTS]
    dispatched = implementations[1:]
    for name, extension in (("c", GenerateC("c")), ("fastrtps_c", GenerateFastRTPSCTypesupport("fastrtps_c")),
                            ("introspection_c", GenerateIntrospectionCTypesupport("introspection_c")),
                            ("typesupport_c", GenerateCTypesupport("c", typesupport_implementations=dispatched)),
                            ("py", GeneratePython("py", typesupport_implementations=implementations))):
        extension.generate(PACKAGE, interface, includes, work / name / PACKAGE)


def compile_all(work):
    """Compile the libraries and the Python extensions; returns {built file: where it is installed}."""
    python = sysconfig.get_paths()["include"]
    import numpy
    includes = [work / "c", work / "fastrtps_c", work / "introspection_c", PREFIX / "include",
                *sorted(p for p in (PREFIX / "include").iterdir() if p.is_dir()), python, numpy.get_include()]
    flags = ["-shared", "-fPIC", "-O2", *(f"-I{p}" for p in includes), f"-L{PREFIX / 'lib'}", f"-L{work / 'lib'}"]
    (work / "lib").mkdir()
    def found(generated, pattern):
        return sorted((work / generated / PACKAGE / "msg").glob(pattern))
    sources = {"rosidl_generator_c": found("c", "detail/*.c"),
               "rosidl_typesupport_fastrtps_c": found("fastrtps_c", "detail/*.cpp"),
               "rosidl_typesupport_introspection_c": found("introspection_c", "detail/*.c"),
               "rosidl_typesupport_c": found("typesupport_c", "*.cpp"),
               "rosidl_generator_py": found("py", "*.c")}
    built = {}
    for library, files in sources.items():
        target = work / "lib" / f"lib{PACKAGE}__{library}.so"
        _compile(files, flags, LINKED[library], target)
        built[target] = PREFIX / "lib" / target.name
    py = work / "py" / PACKAGE
    for name in TYPESUPPORTS:
        target = py / f"{PACKAGE}_s__rosidl_typesupport_{name}.so"
        _compile([py / f"_{PACKAGE}_s.ep.rosidl_typesupport_{name}.c"], flags,
                 [f"{PACKAGE}__rosidl_generator_py", f"{PACKAGE}__rosidl_typesupport_{name}",
                  f"{PACKAGE}__rosidl_generator_c", "rosidl_runtime_c"], target)
    return built


def _compile(files, flags, libraries, target):
    compiler = "g++" if any(f.suffix == ".cpp" for f in files) else "gcc"
    command = [compiler, *flags, *map(str, files), *(f"-l{name}" for name in libraries), "-o", str(target)]
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"build_messages: {compiler} could not build {target.name}:\n{done.stderr[-2000:]}")


def install(work, built, stamp):
    """Copy the libraries, the Python package, the interface files and the ament index entries into place."""
    for source, target in built.items():
        shutil.copy(source, target)
    package = SITE / PACKAGE
    shutil.rmtree(package, ignore_errors=True)
    shutil.copytree(work / "py" / PACKAGE, package, ignore=shutil.ignore_patterns("*.c"))
    (package / "__init__.py").write_text(f'"""{PACKAGE}: built by src/drive_common/build_messages.py."""\n')
    share = PREFIX / "share" / PACKAGE / "msg"
    share.mkdir(parents=True, exist_ok=True)
    for suffix in (".msg", ".idl"):
        shutil.copy(SOURCE / f"{MESSAGE}{suffix}", share)
    index = PREFIX / "share" / "ament_index" / "resource_index"
    for kind, text in (("packages", ""), ("rosidl_interfaces", f"msg/{MESSAGE}.idl\nmsg/{MESSAGE}.msg\n")):
        (index / kind).mkdir(parents=True, exist_ok=True)
        (index / kind / PACKAGE).write_text(text)
    (package / "BUILT_FROM").write_text(stamp)


def main():
    stamp = fingerprint()
    built_from = SITE / PACKAGE / "BUILT_FROM"
    if built_from.is_file() and built_from.read_text() == stamp:
        return 0
    with tempfile.TemporaryDirectory(prefix="drive_msgs_") as work:
        work = Path(work)
        generate(work)
        install(work, compile_all(work), stamp)
    print(f"build_messages: {PACKAGE}/msg/{MESSAGE} built into {PREFIX}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
