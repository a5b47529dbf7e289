from setuptools import find_packages, setup

package_name = "motor_params"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    package_data={"motor_params": ["motors/*.yaml"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description='What the drive knows of its motor and inverter',
    license="Apache-2.0",
)
