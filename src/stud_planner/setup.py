"""ament_python package stud_planner: console scripts go to lib/stud_planner/ so `ros2 run` finds them."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "stud_planner"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/data", glob("data/*")),
    ],
    install_requires=["setuptools"],
    extras_require={"test": ["pytest"]},  # colcon test runs pytest over the testpaths in setup.cfg
    zip_safe=False,
    maintainer="Stud welding maintainers",
    maintainer_email="maintainers@stud-welding.org",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "selfcheck = stud_planner.selfcheck:main",
            "drawing = stud_planner.drawing.drawing_node:main",
            "drawing_inspect = stud_planner.drawing.inspect_cli:main",
            "matcher = stud_planner.matching.matcher_node:main",
            "plan = stud_planner.offline_plan:main",
            # The used-by names of the executables that moved to their own packages (`ros2 run stud_planner
            # cell` keeps working): resolved when run, so stud_planner imports none of these packages.
            "hmi = stud_hmi.hmi_node:main",
            "cell_sequencer = stud_cell.sequencer_node:main",
            "hand_eye_calibrator = stud_cell.hand_eye_calibrator_node:main",
            "inspector = stud_inspection.inspector_node:main",
            "cell = stud_bringup.launch:main",
            "demo = stud_bringup.demo:main",
        ],
    },
)
