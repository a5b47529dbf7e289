from setuptools import find_packages, setup

package_name = "drive_common"

setup(
    name=package_name,
    version="0.3.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    package_data={"drive_common": ["motor/motors/*.yaml", "config/scenarios/*.yaml", "contract/msg/*"]},
    install_requires=["setuptools"],
    zip_safe=False,
    description="What the drive's packages share: motor, configuration, the contract and its records, control math",
    license="Apache-2.0",
)
