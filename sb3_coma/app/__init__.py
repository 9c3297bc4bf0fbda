"""The application: training runs, configs, the rl-zoo entry, shipped models, export and the evaluation front door."""
