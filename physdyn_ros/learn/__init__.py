"""The learned dynamics model (torch; no rclpy, no pybullet). Modules, each imported on its own:

frames      the canonical learning frame C (world <-> C transforms, increments)      numpy
prior       Coulomb sliding as a per-step prior of the network (model.prior)
views       partial clouds as one depth camera sees them                           numpy
rules       physical consistency of predicted trajectories (rest, topple)           numpy
model       PointNet shape encoder + LSTM (or MLP) state predictor, roll-out kernel
windows     dataset -> training windows / evaluation sequences, normalisation statistics
losses      the paper's relative losses with an epsilon
checkpoint  save / load / validate checkpoints
train       `physdyn train`            evaluate  `physdyn evaluate`            baselines  analytic, pybullet
"""
