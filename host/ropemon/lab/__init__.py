"""The lab: the hoist simulator (truth), test bed, evaluation, benchmarks and the demo.

The product (ropemon.station, ropemon.commission) never imports it."""
