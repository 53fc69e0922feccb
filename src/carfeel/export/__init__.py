"""Export carfeel's models for other tools: self-contained C co-simulation FMUs (`fmu`)."""
