"""The run directory: training (the loop that owns the files), checkpoints (the file
format), config.json / run.json, progress.csv and TensorBoard, the one-writer lock, the rules
for starting a run in a directory, atomic writes. run_files, run_lock, run_record and atomic
are torch-free (the CLI uses them).
"""
