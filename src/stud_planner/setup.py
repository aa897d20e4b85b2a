"""ament_python package stud_planner: console scripts go to lib/stud_planner/ so `ros2 run` finds them."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "stud_planner"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "tests"]),
    package_data={PACKAGE: ["hmi_static/*"]},  # the HMI page (stud_planner/hmi_static/)
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*")),
        (f"share/{PACKAGE}/data", glob("data/*")),
    ],
    install_requires=["setuptools"],
    zip_safe=False,
    maintainer="Stud welding maintainers",
    maintainer_email="maintainers@stud-welding.org",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "selfcheck = stud_planner.selfcheck:main",
            "drawing = stud_planner.drawing_node:main",
            "drawing_inspect = stud_planner.drawing_inspect:main",
            "matcher = stud_planner.matcher_node:main",
            "hmi = stud_planner.hmi_node:main",
            "cell_sequencer = stud_planner.cell_sequencer:main",
            "plan = stud_planner.offline_plan:main",
            "demo = stud_planner.demo:main",
            "cell = stud_planner.cell_launch:main",
            "hand_eye_calibrator = stud_planner.hand_eye_calibrator:main",
            "inspector = stud_planner.inspection_node:main",
        ],
    },
)
