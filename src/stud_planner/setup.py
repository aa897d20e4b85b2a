"""ament_python package stud_planner: console scripts go to lib/stud_planner/ so `ros2 run` finds them."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "stud_planner"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    package_data={f"{PACKAGE}.hmi": ["static/*"]},  # the HMI page (stud_planner/hmi/static/)
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
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
            "drawing = stud_planner.drawing.node:main",
            "drawing_inspect = stud_planner.drawing.inspect_cli:main",
            "matcher = stud_planner.matching.node:main",
            "hmi = stud_planner.hmi.node:main",
            "cell_sequencer = stud_planner.cell.sequencer_node:main",
            "plan = stud_planner.offline_plan:main",
            "demo = stud_planner.demo:main",
            "cell = stud_planner.cell.launch:main",
            "hand_eye_calibrator = stud_planner.cell.hand_eye_calibrator:main",
            "inspector = stud_planner.cell.inspector_node:main",
        ],
    },
)
