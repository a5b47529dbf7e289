from setuptools import find_packages, setup

package_name = "foc_controller"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    entry_points={"console_scripts": ["controller_node = foc_controller.node:main"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description='Cascade FOC core (speed PI, d/q current PIs, voltage limiting), PI tuning (no rclpy), an',
    license="Apache-2.0",
)
