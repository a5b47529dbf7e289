from setuptools import find_packages, setup

package_name = "drive_tools"

setup(
    name=package_name,
    version="0.3.0",
    packages=find_packages(exclude=["test"]),
    package_data={"drive_tools.view": ["page.html"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    entry_points={"console_scripts": ["drive = drive_tools.cli.entry:main"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description="What composes the cores: runner, ROS graph launcher, recordings, evaluation and the drive command",
    license="Apache-2.0",
)
