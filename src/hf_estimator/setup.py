from setuptools import find_packages, setup

package_name = "hf_estimator"

setup(
    name=package_name,
    version="0.2.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    entry_points={"console_scripts": ["estimator_node = hf_estimator.node:main",
                                      "commissioning_node = hf_estimator.commissioning.node:main"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description='Rotor angle estimators (HF-injection and a sensored pass-through) as numba cores (no rcl',
    license="Apache-2.0",
)
