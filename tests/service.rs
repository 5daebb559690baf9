//! The live service: the line protocol, the state file (a crash loses nothing accepted), and
//! TCP with clients that come and go.

use std::io::{BufRead, BufReader, Cursor, Write};
use std::net::TcpStream;

use serde_json::{Value, json};

use plumenet::service::{StateFile, serve_lines, serve_tcp};
use plumenet::sim::{EpisodeConfig, run_episode};
use plumenet::ste::posterior::Sample;
use plumenet::ste::protocol::{NoJournal, Protocol};
use plumenet::ste::replay::replay;
use plumenet::ste::session::{Session, SessionConfig};
use plumenet::ste::{Feature, SensorPreset};

use crate::ste::world;

/// The settings of `localize`'s default rank run with seed 1.
fn config() -> SessionConfig {
    EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII).session(1)
}

fn protocol() -> Protocol {
    Protocol::new(
        Session::new(&world().room, config()).unwrap(),
        "wind-tunnel",
        "solver",
    )
}

/// Readings of one simulated run, to stream.
fn readings() -> Vec<Sample> {
    run_episode(
        world(),
        &EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII),
        [4.5, 2.5],
        [15.0, 1.0],
        2,
        false,
    )
    .unwrap()
    .samples
}

fn request(id: usize, op: &str, extra: Value) -> String {
    let mut r = json!({"id": id, "op": op});
    if let (Some(r), Some(extra)) = (r.as_object_mut(), extra.as_object()) {
        r.extend(extra.clone());
    }
    r.to_string()
}

fn replies(protocol: &mut Protocol, lines: &[String]) -> Vec<Value> {
    let mut out = Vec::new();
    let n = serve_lines(
        protocol,
        &mut NoJournal,
        Cursor::new(lines.join("\n\n")),
        &mut out,
    )
    .unwrap();
    assert_eq!(n, lines.len());
    String::from_utf8(out)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn the_protocol_answers_in_order_and_refuses_bad_requests_cleanly() {
    let data = readings();
    let mut p = protocol();
    let lines = vec![
        request(1, "hello", json!({})),
        request(2, "iterate", json!({"position": [15.0, 1.0]})),
        request(3, "readings", json!({"readings": &data[..300]})),
        request(4, "readings", json!({"readings": &data[300..]})),
        request(5, "iterate", json!({})),
        request(6, "belief", json!({})),
        "not json".to_string(),
        request(7, "fly", json!({})),
        request(
            8,
            "readings",
            json!({"readings": [{"t": 0.0, "x": 1.0, "y": 1.0, "value": 1.0}]}),
        ),
        request(
            9,
            "readings",
            json!({"readings": [{"t": 1e9, "x": 40.0, "y": 1.0, "value": 1.0}]}),
        ),
        request(10, "readings", json!({"readings": [{"t": 1e9, "x": 1.0}]})),
        request(11, "belief", json!({})),
        request(12, "reset", json!({})),
        request(13, "iterate", json!({})),
    ];
    let r = replies(&mut p, &lines);
    assert_eq!(r.len(), lines.len());
    assert_eq!(r[0]["protocol"], 1);
    assert_eq!(r[0]["candidates"], 1112);
    assert_eq!(
        (r[0]["feature"].as_str(), r[0]["model"].as_str()),
        (Some("rank"), Some("solver"))
    );
    assert!(r[1]["goal"].is_array() && r[1]["iteration"] == 0);
    assert_eq!(r[2]["accepted"], 300);
    assert_eq!(r[3]["accepted"], data.len());
    assert_eq!(r[4]["iteration"], 1);
    assert_eq!(r[4]["readings"], data.len());
    // `belief` is what `replay` gives for the same readings.
    let est = replay(world().room.samplers(), config().ste, 0.07, &data).unwrap();
    let posterior = r[5]["posterior"].as_array().unwrap();
    for (p, q) in posterior.iter().zip(est.posterior()) {
        assert!((p["p"].as_f64().unwrap() - q).abs() < 1e-12);
    }
    assert_eq!(r[5]["estimate"], json!(est.estimate()));
    // Its uncertainty too: the credible regions and expected distance, with no source to score.
    let u: plumenet::ste::Uncertainty =
        serde_json::from_value(r[5]["uncertainty"].clone()).unwrap();
    assert_eq!(u, est.uncertainty(None));
    assert!(u.source.is_none() && u.regions.len() == 2);
    for (k, needle) in [
        (6, "malformed request"),
        (7, "unknown variant `fly`"),
        (8, "goes back in time"),
        (9, "outside the arena"),
        (10, "missing field"),
    ] {
        assert_eq!(r[k]["ok"], false, "{}", r[k]);
        assert!(r[k]["error"].as_str().unwrap().contains(needle), "{}", r[k]);
    }
    assert_eq!(r[6]["id"], Value::Null);
    assert_eq!(r[7]["id"], 7);
    // The refused requests changed nothing.
    assert_eq!(r[11]["posterior"], r[5]["posterior"]);
    assert_eq!(r[12]["ok"], true);
    let err = r[13]["error"].as_str().unwrap();
    assert!(err.contains("no position to plan from"), "{err}");
}

#[test]
fn the_state_file_survives_a_crash_and_drops_a_torn_line() {
    let data = readings();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("state.jsonl");
    let (mut file, restored) = StateFile::open(&path, OWNER).unwrap();
    assert!(restored.readings.is_empty());
    let header = std::fs::read(&path).unwrap();
    assert_eq!(
        header,
        format!("{{\"plumenet_state\":1,\"session\":\"{OWNER}\"}}\n").into_bytes()
    );
    let mut p = protocol();
    let batches: Vec<&[Sample]> = data.chunks(97).collect();
    for (k, batch) in batches.iter().enumerate() {
        let reply = p.handle(
            &request(k, "readings", json!({"readings": batch})),
            &mut file,
        );
        assert!(reply.contains("\"ok\":true"), "{reply}");
    }
    p.handle(&request(99, "iterate", json!({})), &mut file);
    let before = p.session().estimator().posterior().to_vec();
    drop(file);
    // A crash in the middle of the next write leaves half a line.
    let intact = std::fs::read(&path).unwrap();
    let mut torn = intact.clone();
    torn.extend_from_slice(br#"[{"t":1e6,"x":1.0,"y":"#);
    std::fs::write(&path, &torn).unwrap();
    let (_, restored) = StateFile::open(&path, OWNER).unwrap();
    assert!(restored.dropped_torn_line);
    assert_eq!(restored.batches, batches.len());
    assert_eq!(restored.readings, data);
    assert_eq!(
        std::fs::read(&path).unwrap(),
        intact,
        "truncated to the intact lines"
    );
    let mut session = Session::new(&world().room, config()).unwrap();
    session.add_readings(&restored.readings).unwrap();
    session.update().unwrap();
    assert_eq!(session.estimator().posterior(), &before[..]);
    // Another session's file is refused, whole, with one line naming both sessions.
    let err = StateFile::open(&path, "layout other, model solver, feature rank")
        .unwrap_err()
        .to_string();
    assert!(
        err.contains(&format!("holds the readings of another session ({OWNER})"))
            && err.contains("not this server's (layout other, model solver, feature rank)"),
        "{err}"
    );
    assert_eq!(
        std::fs::read(&path).unwrap(),
        intact,
        "a refused file is left as it was"
    );
    // A reset keeps only the header; damage before the last line is an error, and a file
    // without a header (not a state file) is refused.
    let (mut file, _) = StateFile::open(&path, OWNER).unwrap();
    p.handle(&request(100, "reset", json!({})), &mut file);
    assert_eq!(std::fs::read(&path).unwrap(), header);
    let mut damaged = header.clone();
    damaged.extend_from_slice(b"[oops]\n[]\n");
    std::fs::write(&path, &damaged).unwrap();
    let err = StateFile::open(&path, OWNER).unwrap_err().to_string();
    assert!(err.contains("state line 1 is damaged"), "{err}");
    std::fs::write(&path, "not a state file\n[]\n").unwrap();
    let err = StateFile::open(&path, OWNER).unwrap_err().to_string();
    assert!(err.contains("has no session header"), "{err}");
    // A file written before state files named their session (batches from the first line, a
    // torn last one) is read as it was and given the header in front of its intact lines.
    let old: Vec<u8> = intact[header.len()..].to_vec();
    let mut torn_old = old.clone();
    torn_old.extend_from_slice(br#"[{"t":1e6"#);
    std::fs::write(&path, &torn_old).unwrap();
    let (_, restored) = StateFile::open(&path, OWNER).unwrap();
    assert_eq!(restored.readings, data);
    assert!(restored.dropped_torn_line);
    assert_eq!(std::fs::read(&path).unwrap(), intact);
    // A header torn by a crash before its line break: the file starts afresh.
    std::fs::write(&path, &header[..20]).unwrap();
    let (_, restored) = StateFile::open(&path, OWNER).unwrap();
    assert!(restored.dropped_torn_line && restored.readings.is_empty());
    assert_eq!(std::fs::read(&path).unwrap(), header);
}

/// A session's name in a state file, as `serve` words it.
const OWNER: &str = "layout wind-tunnel 0123456789abcdef, model solver solver-0.1.0, feature rank";

#[test]
fn tcp_clients_come_and_go_and_the_session_goes_on() {
    let data = readings();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut p = protocol();
        serve_tcp(&mut p, &mut NoJournal, "127.0.0.1:0", |at| {
            tx.send(at).unwrap();
        })
        .unwrap();
    });
    let at = rx.recv().unwrap();
    let talk = |lines: &[String], leave_early: bool| -> Vec<Value> {
        let stream = TcpStream::connect(at).unwrap();
        let mut reader = BufReader::new(stream.try_clone().unwrap());
        let mut writer = stream;
        let mut out = Vec::new();
        for line in lines {
            writeln!(writer, "{line}").unwrap();
            let mut reply = String::new();
            reader.read_line(&mut reply).unwrap();
            out.push(serde_json::from_str(&reply).unwrap());
        }
        if leave_early {
            // Sent without waiting for the reply, then gone.
            writeln!(writer, "{}", request(0, "hello", json!({}))).unwrap();
        }
        out
    };
    let half = data.len() / 2;
    let a = talk(
        &[request(1, "readings", json!({"readings": &data[..half]}))],
        true,
    );
    assert_eq!(a[0]["accepted"], half);
    let b = talk(
        &[
            request(2, "readings", json!({"readings": &data[half..]})),
            request(3, "iterate", json!({})),
        ],
        false,
    );
    assert_eq!(b[0]["accepted"], data.len());
    assert_eq!(b[1]["readings"], data.len());
}

/// End to end: a simulated robot steered over TCP by a served session ends exactly where
/// `localize` (the same session in-process) ends, with the same seed and settings.
#[test]
fn a_robot_steered_over_tcp_matches_localize() {
    use plumenet::service::RemoteSession;
    use plumenet::sim::episode::simulate_robot;
    let seed = 6;
    let (source, start) = ([5.1, 2.1], [15.0, 1.0]);
    let c = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let session = Session::new(
            &world().room,
            EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII).session(seed),
        )
        .unwrap();
        let mut p = Protocol::new(session, "wind-tunnel", "solver");
        serve_tcp(&mut p, &mut NoJournal, "127.0.0.1:0", |at| {
            tx.send(at).unwrap();
        })
        .unwrap();
    });
    let mut remote = RemoteSession::connect(rx.recv().unwrap()).unwrap();
    let run = simulate_robot(
        &world().reality,
        &c.flight(),
        [source, start],
        seed,
        c.termination.max_iterations,
        &mut remote,
    )
    .unwrap();
    let local = run_episode(world(), &c, source, start, seed, false).unwrap();
    assert_eq!(run.last.estimate, local.estimate);
    assert_eq!(run.legs, local.iterations);
    assert_eq!(run.readings, local.samples.len());
    assert_eq!(run.last.converged, local.converged);
    assert!((run.error_m - local.error_m).abs() < 1e-12);
    // A refused request comes back as an error naming the server's reason.
    let err = remote.call("fly", json!({})).unwrap_err().to_string();
    assert!(err.contains("the server refused fly"), "{err}");
}

/// Every kind of hostile line gets one error reply naming the problem, changes nothing, and the
/// server goes on serving.
#[test]
fn hostile_lines_are_refused_one_by_one_and_the_session_goes_on() {
    let data = readings();
    let mut p = protocol();
    let reading = |value: &str| format!(r#"{{"t":1.0,"x":15.0,"y":1.0,"value":{value}}}"#);
    let after = data[199].t + 1.0;
    let huge: Vec<Value> = (0..200_000)
        .map(|k| json!({"t": after + k as f64 * 0.01, "x": 15.0, "y": 1.0, "value": 1.0}))
        .collect();
    let lines = vec![
        request(1, "readings", json!({"readings": &data[..200]})),
        "[1,2]".to_string(),
        "42".to_string(),
        r#""hello""#.to_string(),
        "null".to_string(),
        r#"{"id":2}"#.to_string(),
        r#"{"id":3,"op":7}"#.to_string(),
        r#"{"id":4,"op":"readings","readings":{"t":1}}"#.to_string(),
        format!(
            r#"{{"id":5,"op":"readings","readings":[{}]}}"#,
            reading(r#""high""#)
        ),
        format!(
            r#"{{"id":6,"op":"readings","readings":[{}]}}"#,
            reading("1e999")
        ),
        format!(
            r#"{{"id":7,"op":"readings","readings":[{}]}}"#,
            reading("null")
        ),
        r#"{"id":8,"op":"iterate","position":[1.0]}"#.to_string(),
        r#"{"id":9,"op":"iterate","position":[1e999,1.0]}"#.to_string(),
        r#"{"id":10,"op":"hello","extra":true}"#.to_string(),
        "{\"id\":11,\"op\":\"readings\",\"readings\":[".to_string(),
        request(12, "readings", json!({"readings": []})),
        request(13, "readings", json!({"readings": huge})),
        request(14, "hello", json!({})),
        request(15, "belief", json!({})),
    ];
    let r = replies(&mut p, &lines);
    assert_eq!(r[0]["accepted"], 200);
    let refusals = [
        (1, "a request is a JSON object", Value::Null),
        (2, "got a number", Value::Null),
        (3, "got a string", Value::Null),
        (4, "got null", Value::Null),
        (5, "missing field `op`", json!(2)),
        (6, "bad request", json!(3)),
        (7, "invalid type: map, expected a sequence", json!(4)),
        (8, "invalid type: string \"high\", expected f64", json!(5)),
        (9, "malformed request", Value::Null),
        (10, "invalid type: null, expected f64", json!(7)),
        (11, "invalid length 1", json!(8)),
        (12, "malformed request", Value::Null),
        (13, "unknown field `extra`", json!(10)),
        (14, "malformed request", Value::Null),
    ];
    for (k, needle, id) in refusals {
        assert_eq!(r[k]["ok"], false, "line {k}: {}", r[k]);
        let error = r[k]["error"].as_str().unwrap();
        assert!(error.contains(needle), "line {k}: {error}");
        assert_eq!(r[k]["id"], id, "line {k}");
    }
    // An empty batch is accepted and adds nothing; a huge one is taken whole.
    assert_eq!(r[15]["accepted"], 200);
    assert_eq!(r[16]["accepted"], 200 + 200_000, "{}", r[16]);
    assert_eq!(r[17]["ok"], true);
    assert_eq!(r[18]["ok"], true);
}
