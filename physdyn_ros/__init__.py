"""physdyn_ros: learned dynamics of pushed 3D objects (Rempe et al., WACV 2020) as a ROS 2 node suite.

The generated ROS interfaces (physdyn_ros.msg / .srv / .action) are installed by the interface build into
the same package directory of the environment. ``extend_path`` lets them be found even when this source
tree shadows the installed copy (running from the repository root).
"""
from pkgutil import extend_path

__path__ = extend_path(__path__, __name__)  # noqa: F821 - merges the generated interface modules

__version__ = "0.1.0"
