"""Training data: procedural materials, real data set readers and HDF5 shards."""
