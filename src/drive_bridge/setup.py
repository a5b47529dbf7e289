from setuptools import find_packages, setup

package_name = "drive_bridge"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    package_data={"drive_bridge": ["scenarios/*.yaml"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description="One-process runner, scenarios, metrics, benchmarks, the drive command line and the "
                "inverter bridge.",
    license="Apache-2.0",
    entry_points={"console_scripts": ["drive = drive_bridge.cli:main",
                                      "drive_node = drive_bridge.graph:node_main"]},
)
