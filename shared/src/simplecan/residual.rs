//! The residual error rate of SimpleCAN against SC_REQ_04, `docs/simplecan.md` section 8.
//!
//! One formula, here and nowhere else: the document's figures and the schedule's check
//! ([`super::schedule::Schedule::new`]) both come from [`rate_per_hour`]. Floating point is
//! used only for this analysis; no protocol decision at run time depends on it except the
//! configuration check, whose bound [`MAX_PACKETS_PER_SECOND`] is a whole number.

/// EN 50325-5 9.4.2 (4): the worst-case residual error probability of one CAN frame.
pub const CAN_RESIDUAL_ERROR_PROBABILITY: f64 = 7e-9;

/// The share of corruptions CAN missed that also pass the CRC-24: 2^-24 (section 4).
pub const CRC_PASS_PROBABILITY: f64 = 1.0 / (1u32 << 24) as f64;

/// SC_REQ_04: 1 % of the highest PFH of SIL 3 (10^-7 per hour).
pub const LIMIT_PER_HOUR: f64 = 1e-9;

/// The most SimpleCAN packets per second a network may carry and stay within
/// [`LIMIT_PER_HOUR`]: `floor(1e-9 / (3600 × 7e-9 × 2^-24)) = 665`
/// (`tests::sc_req_04_the_packet_rate_bound_is_665_per_second` derives it).
pub const MAX_PACKETS_PER_SECOND: u32 = 665;

/// The residual error probability of one SimpleCAN packet: `R(P_CAN) × 2^-24` (step 2).
pub fn probability_per_packet() -> f64 {
    CAN_RESIDUAL_ERROR_PROBABILITY * CRC_PASS_PROBABILITY
}

/// `Λ_SL = 3600 s/h × R_SL × ν` (steps 3 and 4, after CiA 304 9.3): the residual error rate
/// per hour of a network that carries `packets_per_second` SimpleCAN packets, data and syncs
/// together.
pub fn rate_per_hour(packets_per_second: f64) -> f64 {
    3600.0 * probability_per_packet() * packets_per_second
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(actual: f64, expected: f64) -> bool {
        (actual - expected).abs() <= expected * 1e-3
    }

    /// Step 2 of section 8: 7e-9 × 2^-24 = 4.17e-16 per packet.
    #[test]
    fn sc_req_04_residual_error_probability_per_packet() {
        assert!(close(probability_per_packet(), 4.172e-16));
        assert!(close(rate_per_hour(1.0), 1.502e-12));
    }

    /// Step 4: 665 packets per second are within 1e-9 per hour, 666 are not.
    #[test]
    fn sc_req_04_the_packet_rate_bound_is_665_per_second() {
        let bound = LIMIT_PER_HOUR / rate_per_hour(1.0);
        assert!(close(bound, 665.76));
        assert_eq!(bound as u32, MAX_PACKETS_PER_SECOND);
        assert!(rate_per_hour(f64::from(MAX_PACKETS_PER_SECOND)) <= LIMIT_PER_HOUR);
        assert!(rate_per_hour(f64::from(MAX_PACKETS_PER_SECOND + 1)) > LIMIT_PER_HOUR);
    }

    /// Step 5's examples, packet rates as the document derives them.
    #[test]
    fn sc_req_04_the_documents_example_networks() {
        // N = 3, one producer slot, a sync every 34 cycles (102 ms).
        let small = 1000.0 / 3.0 + 1000.0 / 102.0;
        assert!(close(rate_per_hour(small), 5.15e-10));
        // N = 10, six producer slots, a sync every 10 cycles (100 ms).
        assert!(close(rate_per_hour(610.0), 9.16e-10));
        // N = 10, seven producer slots: over the limit.
        assert!(close(rate_per_hour(710.0), 1.066e-9));
        assert!(rate_per_hour(710.0) > LIMIT_PER_HOUR);
    }
}
