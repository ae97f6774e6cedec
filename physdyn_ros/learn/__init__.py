"""The learned dynamics model (torch; no rclpy, no pybullet). Modules, each imported on its own:

frames      the canonical learning frame C (world <-> C transforms, increments)      numpy
model       PointNet shape encoder + LSTM (or MLP) state predictor, roll-out kernel
windows     dataset -> training windows / evaluation sequences, normalisation statistics
losses      the paper's relative losses with an epsilon
checkpoint  save / load / validate checkpoints
train       `physdyn train`            evaluate  `physdyn evaluate`            baselines  analytic, pybullet
"""
