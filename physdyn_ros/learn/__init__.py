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
"""The learned dynamics model (torch; no rclpy, no pybullet). Modules, each imported on its own:

frames       the canonical learning frame C (world <-> C transforms, increments)             numpy
prior        Coulomb sliding as a per-step prior of the network (model.prior)
views        partial clouds as one depth camera sees them                                  numpy
rules        physical consistency of predicted trajectories (rest, topple)                  numpy
support      support-polygon descriptors and per-push quantities of the topple head        numpy
topple       the whole-push topple head                   topple_fit  `physdyn fit-topple`
model        PointNet shape encoder + LSTM (or MLP) state predictor, its config and entry points
kernels      the roll-out loops (TorchScript, fused, numpy batch 1, MLP) and their weight layouts
windows      dataset -> training windows / evaluation sequences, normalisation statistics
losses       the paper's relative losses with an epsilon
sections     config sections: known keys, removed options
config       a run's config (train and data sections; a whole config from YAML and overrides)
checkpoint   save / load / validate checkpoints
distributed  single process or DDP under torchrun
loop         the training loop (a run's state, epochs, validation)
train        `physdyn train`              evaluate  `physdyn evaluate`              baselines  analytic, pybullet
"""
