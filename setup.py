"""ament_python package metro_atc (the repo root)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "metro_atc"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    package_data={PACKAGE: ["scenarios/*.yaml", "scenarios/*.md", "data/*", "data/ttobench/*",
                            "ttobench/*.md"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.xml")
         + glob("config/*.json")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="metro_atc maintainers",
    maintainer_email="maintainers@metro-atc.invalid",
    description="Metro signalling / ATC emulator as a ROS 2 node graph",
    license="Apache-2.0",
    extras_require={"test": ["pytest"]},
    entry_points={
        "console_scripts": [
            f"line_simulator = {PACKAGE}.nodes.line_simulator:main",
            f"ats_regulator = {PACKAGE}.nodes.ats_regulator:main",
            f"ato_controller = {PACKAGE}.nodes.ato_controller:main",
            f"brake_diagnostic = {PACKAGE}.nodes.brake_diagnostic:main",
            f"bag_recorder = {PACKAGE}.nodes.bag_recorder:main",
            f"foxglove_bridge = {PACKAGE}.nodes.foxglove_bridge:main",
        ],
    },
)
