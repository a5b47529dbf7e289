from setuptools import find_packages, setup

package_name = "drive_scenarios"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    package_data={"drive_scenarios": ["scenarios/*.yaml"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description='Scenarios',
    license="Apache-2.0",
)
