from setuptools import find_packages, setup

package_name = "pmsm_plant"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    entry_points={"console_scripts": ["plant_node = pmsm_plant.node:main"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description='PMSM plant core',
    license="Apache-2.0",
)
