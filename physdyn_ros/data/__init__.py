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
"""Dataset format v1 (manifest + shapes.npz + shards), reader and object-level splits. numpy only."""
from .format import FORMAT_NAME, FORMAT_VERSION, SHARD_FIELDS, Dataset, check_shard, load_npz, sha256_file, \
    stack_sims, write_json, write_npz
from .splits import SPLITS, check_disjoint, leave_one_category_out, make_splits

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "SHARD_FIELDS", "SPLITS", "Dataset", "check_disjoint", "check_shard",
           "leave_one_category_out", "load_npz", "make_splits", "sha256_file", "stack_sims", "write_json",
           "write_npz"]
