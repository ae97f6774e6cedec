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
"""The parts of `physdyn generate` (physdyn_ros.sim.generate, the command and its `generate()`), one job each:

- `params`: the generator's parameters: defaults <- YAML config <- command line, validated;
- `workers`: the shapes and shard plan, one shard's simulations, the worker pool that computes the pending shards;
- `manifest`: the dataset's manifest on disk: locked read-modify-write, adopting finished shards, the counts.
"""
