"""Live mode: estimators fed by measurements as they arrive over the network.

``graphpos live`` (:mod:`graphpos.cli.live`) listens on UDP or TCP for one
JSON message per datagram or line, checks each message
(:mod:`graphpos.live.protocol`, or :mod:`graphpos.live.rosbridge` for ROS
topics through an import mapping), feeds the online estimators
(:mod:`graphpos.live.session`), publishes every estimate as it is produced
on a Foxglove WebSocket server (:mod:`graphpos.live.foxglove_out`) and
records inputs and outputs to an MCAP file that reads after any stop
(:mod:`graphpos.io.mcap_recorder`). ``graphpos replay`` (:mod:`graphpos.live.replay`)
sends a recorded drive at its recorded arrival times, optionally damaged as a
real network damages it.
"""
