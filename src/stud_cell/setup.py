"""ament_python package stud_cell: console scripts go to lib/stud_cell/ so `ros2 run` finds them."""
from setuptools import find_packages, setup

PACKAGE = "stud_cell"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest over the testpaths in setup.cfg
    zip_safe=False,
    maintainer="Stud welding maintainers",
    maintainer_email="maintainers@stud-welding.org",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "cell_sequencer = stud_cell.sequencer_node:main",
            "hand_eye_calibrator = stud_cell.hand_eye_calibrator_node:main",
        ],
    },
)
