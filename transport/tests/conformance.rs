//! The conformance suite (`tests/common/suite.rs`) against the in-process link and iceoryx2.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[macro_use]
mod common;

mod inproc_link {
    use super::common;
    use h4_shared::wire::{Command, Feedback};
    use h4_transport::inproc::{self, InprocEnd};

    struct Inproc;

    impl common::suite::Transport for Inproc {
        type Master = InprocEnd<Command, Feedback>;
        type Slave = InprocEnd<Feedback, Command>;
        fn open(arms: &[u16]) -> Vec<(Self::Master, Self::Slave)> {
            // In one process each arm has its own pair, as each arm's processes would.
            arms.iter().map(|_| inproc::pair(64)).collect()
        }
    }

    conformance_suite!(Inproc);
}

#[cfg(feature = "iceoryx2")]
mod iceoryx2_link {
    use super::common;
    use h4_shared::wire::{Command, Feedback};
    use h4_transport::Link;
    use h4_transport::iceoryx2::{self as iox, Iceoryx2Link, Iceoryx2Options};

    struct Iox;

    fn options(prefix: &str, arm_id: u16) -> Iceoryx2Options {
        Iceoryx2Options {
            prefix: prefix.to_string(),
            ..Iceoryx2Options::new(arm_id)
        }
    }

    impl common::suite::Transport for Iox {
        type Master = Iceoryx2Link<Command, Feedback>;
        type Slave = Iceoryx2Link<Feedback, Command>;
        fn open(arms: &[u16]) -> Vec<(Self::Master, Self::Slave)> {
            // One service prefix per test, so tests running in parallel never meet.
            let prefix = common::unique_name("h4test");
            arms.iter()
                .map(|&arm| {
                    let opts = options(&prefix, arm);
                    (iox::master(&opts).unwrap(), iox::slave(&opts).unwrap())
                })
                .collect()
        }
    }

    conformance_suite!(Iox);

    #[test]
    fn restarted_peer_re_pairs() {
        // The slave end is dropped, as a killed process's would be, and a new one opens the
        // same services: messages flow again with no action on the master's side.
        let opts = options(&common::unique_name("h4test"), 31);
        let mut master = iox::master(&opts).unwrap();
        let mut slave = iox::slave(&opts).unwrap();
        common::suite::connect(&mut master, &mut slave, 31);
        drop(slave);
        let mut slave = iox::slave(&opts).unwrap();
        let mut seq = 100;
        let deadline = std::time::Instant::now() + common::suite::WATCHDOG;
        let got = loop {
            master.publish(&common::suite::command(31, seq)).unwrap();
            seq += 1;
            std::thread::sleep(std::time::Duration::from_millis(2));
            if let Some(c) = slave.recv_latest().unwrap() {
                break c;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "watchdog: no re-pairing"
            );
        };
        assert!(got.seq >= 100);
    }
}
