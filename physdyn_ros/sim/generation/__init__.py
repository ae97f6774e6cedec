"""The parts of `physdyn generate` (physdyn_ros.sim.generate, the command and its `generate()`), one job each:

- `params`: the generator's parameters: defaults <- YAML config <- command line, validated;
- `workers`: the shapes and shard plan, one shard's simulations, the worker pool that computes the pending shards;
- `manifest`: the dataset's manifest on disk: locked read-modify-write, adopting finished shards, the counts.
"""
