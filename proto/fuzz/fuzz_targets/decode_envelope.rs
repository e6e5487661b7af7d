//! Arbitrary bytes into the envelope decoder every peer runs first: it must never
//! panic, and whatever it accepts must survive an encode/decode round trip unchanged.

#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    match paddock_proto::decode(data) {
        Ok((rid, body)) => {
            let name = paddock_proto::body_name(&body);
            let again = paddock_proto::encode(rid, body);
            let (rid2, body2) = paddock_proto::decode(&again)
                .unwrap_or_else(|(_, e)| panic!("re-encoded {name} does not decode: {e}"));
            assert_eq!(rid, rid2);
            // compared as bytes: a NaN double is a valid value but not equal to itself
            assert_eq!(paddock_proto::encode(rid2, body2), again, "{name} changed");
        }
        Err((_, e)) => {
            // every refusal has a reply naming it
            let reply = e.to_error();
            assert!(!reply.message.is_empty());
        }
    }
});
