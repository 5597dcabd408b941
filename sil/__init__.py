"""balloon-sil: the simulator, the firmware and the ground station as separate processes over UDP on loopback."""
