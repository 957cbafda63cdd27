"""The run directory: training (the loop that owns the files), checkpoints (the file
format), config.json / run.json, progress.csv and TensorBoard, the one-writer lock, the rules
for starting a run in a directory, atomic writes, when a run is finished (completion).
run_files, run_lock, run_record, atomic and completion are torch-free (the CLI uses them).
"""
