from setuptools import find_packages, setup

PACKAGE = "perch_operator"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={PACKAGE: ["*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        # `ros2 launch perch_operator perch.launch.py` and the graph's parameter file in share/
        (f"share/{PACKAGE}/launch", ["launch/perch.launch.py"]),
        (f"share/{PACKAGE}/config", ["config/perch.yaml", "config/fastdds.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Perch developers",
    maintainer_email="perch@example.com",
    description="Operator stage of Perch: crop, mission coordination, confirmation, waypoints, "
                "recording, replay, reports and the demo.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{PACKAGE}_node = {PACKAGE}.node:main"],
        "perch.commands": [
            "plan = perch_operator.cli:register_plan",
            "demo = perch_operator.cli:register_demo",
            "operator = perch_operator.cli_operator:register",
            "replay = perch_operator.cli_operator:register_replay",
            "view = perch_operator.cli_operator:register_view",
            "dispatch = perch_operator.cli_operator:register_dispatch",
            "record = perch_operator.cli_operator:register_record",
        ],
        "perch.benchmarks": ["mission = perch_operator.bench:register", "soak = perch_operator.soak:register",
                             "memory = perch_operator.bench_memory:register"],
        "perch.nodes": [f"{PACKAGE} = {PACKAGE}.node:main"],
    },
)
