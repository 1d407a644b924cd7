"""The plant simulator: hoist, head and tail ropes, the N-cylinder hydraulic
connection device, seal friction, oil and the node's sensors, with ground truth.

docs/simulator.md describes the model, the numerical method and the scenario
files; docs/model.md fixes the signs and units followed here.
"""
