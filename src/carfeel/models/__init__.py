"""Pure physics models: `step(state, inputs, params, dt_s) -> (state, outputs)`.

Nothing here imports any other part of carfeel, does I/O, reads a clock or keeps globals; the same
step runs in the offline simulator, the real-time loop and the identification fits.
"""
