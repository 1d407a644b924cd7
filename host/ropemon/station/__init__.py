"""The hoist-room station: receivers, decode and merge, alarms, store and the views."""
