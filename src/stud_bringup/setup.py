"""ament_python package stud_bringup: console scripts go to lib/stud_bringup/ so `ros2 run` finds them."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "stud_bringup"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest over the testpaths in setup.cfg
    zip_safe=False,
    maintainer="Stud welding maintainers",
    maintainer_email="maintainers@stud-welding.org",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "cell = stud_bringup.launch:main",
            "demo = stud_bringup.demo:main",
        ],
    },
)
