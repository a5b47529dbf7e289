from setuptools import find_packages, setup

package_name = "drive_cli"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    entry_points={"console_scripts": ["drive = drive_cli.entry:main"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description='The `drive` command line.',
    license="Apache-2.0",
)
