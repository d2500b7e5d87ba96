from setuptools import find_packages, setup

PACKAGE = "perch_segmentation"

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
    description="Segmentation stage of Perch: planar surfaces of a room mesh.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{PACKAGE}_node = {PACKAGE}.node:main"],
        "perch.commands": ["segment = perch_segmentation.cli:register"],
        "perch.benchmarks": ["segment = perch_segmentation.bench:register"],
        "perch.nodes": [f"{PACKAGE} = {PACKAGE}.node:main"],
    },
)
