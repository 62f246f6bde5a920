"""Cycler data: records, readers, resampling to the model's sample time, SoC references."""
