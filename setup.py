"""ament_python package setup for eye_in_hand.

The ROS 2 Python wheels are the ``ros`` extra, not an install requirement, so that a
``colcon build`` against a system ROS 2 install does not pull them from PyPI.
"""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = "eye_in_hand"

# One console script per node, so that ``ros2 run eye_in_hand <node>`` works on a ROS install.
NODE_SCRIPTS = [
    "bag_player = eye_in_hand.nodes.bag_player:main",
    "bag_recorder = eye_in_hand.nodes.bag_recorder:main",
    "hand_eye = eye_in_hand.nodes.hand_eye:main",
    "stereo_capture = eye_in_hand.nodes.stereo_capture:main",
    "detect_triangulate = eye_in_hand.nodes.detect_triangulate:main",
    "localize = eye_in_hand.nodes.localize:main",
]

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*", "benchmarks"]),
    package_data={PACKAGE: ["py.typed", "ros/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml") + glob("config/*.rviz")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    python_requires=">=3.10",
    # Each minimum is the version pinned in .ci/min-constraints.txt, where `make test-min-deps`
    # runs the bag, offline and calibration tests (docs/development.md, "Dependencies"). Below
    # them: rosbags < 0.11.6 lacks storage_mcap.get_msgdef (io/bags/reading.py's MCAP scanner);
    # OpenCV 4.x has no criteria argument in undistortPoints (core/camera.py); scipy < 1.15.2
    # refuses read-only matrices in Rotation.from_matrix; OpenCV 5 needs numpy 2, and
    # matplotlib < 3.8.4 is built for numpy 1.
    install_requires=[
        "numpy>=2.0.0",
        "scipy>=1.15.2",
        "opencv-python-headless>=5.0.0.93",
        "rosbags>=0.11.6",
        "lz4>=4.0.2",
        'backports.zstd>=1.0.0; python_version < "3.14"',  # compression.zstd from 3.14 on
        "zstandard>=0.25.0",          # zstd chunks: 2x faster here than backports.zstd
        "pyyaml>=6.0.1",
        "matplotlib>=3.8.4",
        "tqdm>=4.66.0",
    ],
    extras_require={
        "ros": [
            "ros-jazzy-rclpy[fastrtps]==7.1.6",
            "ros-jazzy-common-interfaces==5.3.6",
        ],
        "test": [
            "pytest>=8",
            "colcon-common-extensions>=0.3",
            "catkin_pkg",  # imported by test_package.py (colcon-ros requires it as well)
            # make lint (docs/development.md, "Lint"): the versions it was made clean with
            "ruff>=0.17.6",
            "mypy>=2.4.1",
            "types-PyYAML>=6.0.12.20261113",
            "types-tqdm>=4.70.0.20261106",
        ],
    },
    zip_safe=True,
    maintainer="eye_in_hand maintainers",
    maintainer_email="maintainers@eye-in-hand.dev",
    description="Eye-in-hand stereo target localization, calibration and bag tools for ROS 2.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "eye-in-hand = eye_in_hand.cli:console_main",
            *NODE_SCRIPTS,
        ],
    },
)
