"""Dataset format v1 (manifest + shapes.npz + shards), reader and object-level splits. numpy only."""
from .format import FORMAT_NAME, FORMAT_VERSION, SHARD_FIELDS, Dataset, check_shard, load_npz, sha256_file, \
    stack_sims, write_json, write_npz
from .splits import SPLITS, check_disjoint, leave_one_category_out, make_splits

__all__ = ["FORMAT_NAME", "FORMAT_VERSION", "SHARD_FIELDS", "SPLITS", "Dataset", "check_disjoint", "check_shard",
           "leave_one_category_out", "load_npz", "make_splits", "sha256_file", "stack_sims", "write_json",
           "write_npz"]
