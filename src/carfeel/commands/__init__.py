"""The command families of `carfeel`, one module each (the way pip and git keep one file per
command): each module's `register(commands)` adds its sub-parser with its options and sets
`handler` (args -> exit code). `carfeel.cli` only assembles them and turns errors into exit codes.
"""
