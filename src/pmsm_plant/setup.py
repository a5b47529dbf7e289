from setuptools import find_packages, setup

package_name = "pmsm_plant"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    description="PMSM plant core: continuous-time dq motor with saturation, averaged inverter, current sensing.",
    license="Apache-2.0",
)
