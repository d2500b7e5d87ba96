from setuptools import find_packages, setup

PACKAGE = "perch_reconstruction"

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
    description="Reconstruction stage of Perch: RGB-D bags or topics to a clean gravity-aligned room mesh.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [f"{PACKAGE}_node = {PACKAGE}.node:main"],
        "perch.commands": [
            "bag = perch_reconstruction.cli:register_bag",
            "clean = perch_reconstruction.cli:register_clean",
            "reconstruct = perch_reconstruction.cli:register_reconstruct",
        ],
        "perch.benchmarks": ["reconstruct = perch_reconstruction.bench:register"],
        "perch.nodes": [f"{PACKAGE} = {PACKAGE}.node:main"],
    },
)
