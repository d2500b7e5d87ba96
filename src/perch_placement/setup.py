from setuptools import find_packages, setup

PACKAGE = "perch_placement"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Perch developers",
    maintainer_email="perch@example.com",
    description="Placement stage of Perch: camera simulation, fitness and greedy swarm search for perches.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{PACKAGE}_node = {PACKAGE}.node:main"],
        "perch.commands": ["place = perch_placement.cli:register"],
        "perch.benchmarks": ["placement = perch_placement.bench:register"],
        "perch.nodes": [f"{PACKAGE} = {PACKAGE}.node:main"],
    },
)
