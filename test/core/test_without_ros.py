"""The core is usable without ROS: importing it, or any module of its subpackages, never
touches rclpy or messages."""

import subprocess
import sys
import textwrap


def test_core_and_every_subpackage_import_and_run_with_ros_unavailable():
    script = textwrap.dedent("""
        import sys
        class NoRos:
            def find_spec(self, name, path=None, target=None):
                top = name.split('.')[0]
                if top in ('rclpy', 'rosidl_runtime_py', 'grasp_fc_msgs', 'std_msgs',
                           'geometry_msgs', 'diagnostic_msgs') or top.startswith('rcl'):
                    raise ImportError('ROS is not installed here: ' + name)
                return None
        sys.meta_path.insert(0, NoRos())
        import numpy as np
        import grasp_fc_ros
        import importlib, pkgutil
        import grasp_fc_ros.core as core
        from grasp_fc_ros.core import check_force_closure
        # Every module of every subpackage, not only what core/__init__ reaches.
        names = [m.name for m in pkgutil.walk_packages(core.__path__, 'grasp_fc_ros.core.')]
        for name in names:
            importlib.import_module(name)
        packages = {m.name for m in pkgutil.iter_modules(core.__path__) if m.ispkg}
        assert {'model', 'filter', 'exact', 'forces', 'quality', '_kernels'} <= packages, packages
        assert len(names) > 25, names
        p = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float)
        assert check_force_closure(p, -p, 0.5).force_closure
        heavy = {'rclpy', 'matplotlib', 'trimesh'} & set(sys.modules)
        assert not heavy, heavy
        print('ok')
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("ok")
