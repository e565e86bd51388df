"""ament_python package: installs console scripts where `ros2 run` looks (see setup.cfg)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "soc_estimator_ros"

# The one list of executables (installed to lib/soc_estimator_ros/ for `ros2 run`, see
# setup.cfg); test/packaging/test_colcon_build.py checks that each one starts (`--help`).
CONSOLE_SCRIPTS = [
    "soc_replay = soc_estimator_ros.replay.cli:main",
    "soc_identify = soc_estimator_ros.identification.cli:main",
    "soc_tune = soc_estimator_ros.tuning.cli:main",
    "soc_estimator_node = soc_estimator_ros.node.ros_node:main",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", sorted(glob("config/*.yaml"))),
        (f"share/{PACKAGE}/launch", sorted(glob("launch/*.launch.py"))),
    ],
    install_requires=["numpy", "scipy", "filterpy", "rosbags", "pyyaml", "matplotlib"],
    extras_require={
        # Developer tool only: tools/make_bags.py simulates the bundled bags with PyBaMM.
        "sim": ["pybamm==26.10.1.1"],
        # Desktop only: soc_replay on a Dask cluster and fsspec URLs (replay/fleet.py).
        "fleet": ["dask[distributed]", "fsspec"],
        # setuptools >= 72 dropped `tests_require` (it only warns "Unknown distribution
        # option"); the test tools are pinned in requirements-test.txt.
        "test": ["pytest"],
    },
    zip_safe=True,
    maintainer="soc_estimator_ros developers",
    maintainer_email="soc-estimator-ros@example.org",
    description="Onboard battery State-of-Charge estimation for small robots (ROS 2 Jazzy).",
    license="Apache-2.0",
    entry_points={"console_scripts": CONSOLE_SCRIPTS},
)
