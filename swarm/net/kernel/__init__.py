"""The network below Zenoh: Linux network namespaces with kernel-level faults (`netns`) and
emulated hosts, one namespace and one Zenoh router per host (`hosts`)."""
