//! What flyd reports about itself in `FLYD_Status`: its [`State`] and its [`FaultBits`].
named_enum! {
    /// flyd's own state.
    pub enum State {
        Init = 0 => "INIT",
        Running = 1 => "RUNNING",
        /// Running with at least one fault bit set; commands fall back to the safe command.
        Degraded = 2 => "DEGRADED",
        /// Cannot produce perception at all.
        Fault = 3 => "FAULT",
        Shutdown = 4 => "SHUTDOWN",
    }
}

bit_set! {
    /// The `FaultBits` signal: one bit per fault, any combination (all 8 bits are defined, so
    /// every `u8` is a valid value).
    pub struct FaultBits(mask 0xFF) {
        /// bit 0: no fresh frame from the left camera.
        const LEFT_CAMERA_STALE = 0 => "LEFT_CAMERA_STALE";
        /// bit 1: no fresh frame from the right camera.
        const RIGHT_CAMERA_STALE = 1 => "RIGHT_CAMERA_STALE";
        /// bit 2: left and right frames too far apart in time to be a stereo pair.
        const STEREO_SKEW = 2 => "STEREO_SKEW";
        /// bit 3: the evolution cannot keep its generation rate.
        const EVOLUTION_OVERRUN = 3 => "EVOLUTION_OVERRUN";
        /// bit 4: the newest perception snapshot is too old.
        const SNAPSHOT_STALE = 4 => "SNAPSHOT_STALE";
        /// bit 5: a camera reports a wrong format or a device error, or a sensor check fails
        /// (which one: [`crate::sensor::SensorFaults`]).
        const CAMERA_ERROR = 5 => "CAMERA_ERROR";
        /// bit 6: CAN transmission errors.
        const CAN_TX_ERROR = 6 => "CAN_TX_ERROR";
        /// bit 7: configuration or internal error (the declared mount off by more than the
        /// road estimator absorbs: [`crate::perception::mount_check`]).
        const INTERNAL = 7 => "INTERNAL";
    }
}
