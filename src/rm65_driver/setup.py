"""ament_python package rm65_driver: console scripts go to lib/rm65_driver/ so `ros2 run` finds them."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "rm65_driver"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
        (f"share/{PACKAGE}/data", glob("data/*")),
        (f"share/{PACKAGE}/urdf", glob("urdf/*")),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest over the testpaths in setup.cfg
    zip_safe=False,
    maintainer="Stud welding maintainers",
    maintainer_email="maintainers@stud-welding.org",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "driver = rm65_driver.driver.driver_node:main",
            # the simulator lives in rm65_sim: this keeps `ros2 run rm65_driver simulator` working (resolved
            # when it runs, so rm65_driver does not depend on rm65_sim)
            "simulator = rm65_sim.simulator:main",
            "state_publisher = rm65_driver.state_publisher_node:main",
        ],
    },
)
