"""What the algorithms share: buffers, extractors, masking, callbacks, checkpoints and evaluation of objects."""
