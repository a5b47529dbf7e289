from setuptools import find_packages, setup

package_name = "drive_commissioning"

setup(
    name=package_name,
    version="0.3.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    entry_points={"console_scripts": ["commissioning_node = drive_commissioning.node:main"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description="Self-commissioning at standstill: a per-sample procedure core (no rclpy) and its node",
    license="Apache-2.0",
)
