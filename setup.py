from setuptools import find_packages, setup

package_name = "grasp_fc_ros"

setup(
    name=package_name,
    version="1.0.0",
    packages=find_packages(exclude=["test", "test.*"]),
    # PEP 561: the package ships its type hints.
    package_data={package_name: ["py.typed"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml", "CHANGELOG.rst", "LICENSE"]),
        ("share/" + package_name + "/config", ["config/force_closure.yaml"]),
        # `ros2 launch grasp_fc_ros force_closure.launch.py` and its RViz config.
        ("share/" + package_name + "/launch", ["launch/force_closure.launch.py"]),
        ("share/" + package_name + "/rviz", ["rviz/force_closure.rviz"]),
    ],
    # rclpy and the grasp_fc_msgs interfaces come from the ROS prefix, not PyPI.
    # scipy: the core hands Clarabel scipy.sparse matrices.
    install_requires=["setuptools", "numpy", "scipy", "clarabel", "numba"],
    extras_require={"experiment": ["matplotlib", "trimesh", "scipy"],
                    "label": ["dask", "distributed", "pyarrow"]},
    zip_safe=True,
    maintainer="grasp_fc_ros maintainers",
    maintainer_email="maintainers@users.noreply.h-seed-30dcbcef.example",
    description="Fast, exact force-closure test for multi-finger frictional grasps.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "grasp-fc-node = grasp_fc_ros.node.cli:main",
            "grasp-fc-demo = grasp_fc_ros.demo:main",
            "grasp-fc-experiment = grasp_fc_ros.experiment.cli:main",
            "grasp-fc-label = grasp_fc_ros.labelling.cli:main",
            "grasp-fc-query = grasp_fc_ros.client.cli:main",
        ],
    },
)
