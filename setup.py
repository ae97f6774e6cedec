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
"""pip install of the physdyn_ros Python package (the ROS interfaces are built by CMake, see setup.sh)."""
from glob import glob

from setuptools import find_packages, setup

NODES = ["perception", "predictor", "sim", "recorder"]

setup(
    name="physdyn_ros",
    version="0.1.0",
    description="Learned dynamics of pushed 3D objects as a ROS 2 Jazzy node suite",
    license="Apache-2.0",
    python_requires=">=3.10",
    packages=find_packages(include=["physdyn_ros", "physdyn_ros.*"]),
    package_data={"physdyn_ros": ["models/*.pt", "models/*.md", "models/*.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/physdyn_ros"]),
        ("share/physdyn_ros", ["package.xml"]),
        ("share/physdyn_ros/config", glob("config/*.yaml") + glob("config/*.xml")),
        ("share/physdyn_ros/config/viz", glob("config/viz/*")),
        ("share/physdyn_ros/launch", glob("launch/*.py")),
    ],
    entry_points={
        "console_scripts": ["physdyn = physdyn_ros.cli:main"]
        + [f"physdyn-{n} = physdyn_ros.nodes.{n}_node:main" for n in NODES],
    },
)
