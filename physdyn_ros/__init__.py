# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""physdyn_ros: learned dynamics of pushed 3D objects (Rempe et al., WACV 2020) as a ROS 2 node suite.

The generated ROS interfaces (physdyn_ros.msg / .srv / .action) are installed by the interface build into
the same package directory of the environment. ``extend_path`` lets them be found even when this source
tree shadows the installed copy (running from the repository root).
"""
from pkgutil import extend_path

__path__ = extend_path(__path__, __name__)  # noqa: F821 - merges the generated interface modules

__version__ = "0.1.0"
