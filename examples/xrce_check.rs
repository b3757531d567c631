//! Checks a DDS-XRCE agent with Courier sessions, step by step, printing
//! what each step saw (for eProsima's MicroXRCEAgent or Courier's own):
//!
//! ```text
//! cargo run --example xrce_check -- <url> pubsub|self|ref|rpc|rpc1|ping|watch [seconds]
//! ```
//! - `pubsub`: two sessions, a writer and a reader: reliable, best effort,
//!   confirmed, a 20 000-byte sample (fragments);
//! - `self`: one session writes and reads its own topic (XML participants
//!   of eProsima's agent do not use its discovery server);
//! - `ref`: entities by reference to the agent's `-r` profiles
//!   (`shapetype_*` of `agent.refs`, topic `Square`, type `ShapeType`);
//! - `rpc`: a replier and a requester (`rpc1`: both in one session, as
//!   one serial line carries one session);
//! - `ping`: ping and time sync;
//! - `watch`: publishes reliably every 100 ms and reads for `seconds`,
//!   printing the session events (kill and restart the agent meanwhile).

use std::time::{Duration, Instant};

use courier::{IpcMessage, PublicationQos, Reliability, Session, SubscriptionQos};
use futures::StreamExt;

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::check::Msg")]
struct Msg {
    seq: u32,
    payload: Vec<u8>,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "ShapeType")]
struct ShapeType {
    #[ipc(key)]
    color: String,
    x: i32,
    y: i32,
    shapesize: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::check::AddRequest")]
struct AddRequest {
    a: i32,
    b: i32,
}

#[derive(IpcMessage, Debug, Clone, PartialEq)]
#[ipc(type_name = "courier::check::AddReply")]
struct AddReply {
    sum: i32,
}

type Res<T> = Result<T, Box<dyn std::error::Error + Send + Sync>>;

const T: Duration = Duration::from_secs(10);

fn msg(seq: u32, len: usize) -> Msg {
    Msg {
        seq,
        payload: (0..len).map(|i| (i as u32 ^ seq) as u8).collect(),
    }
}

async fn next<M: IpcMessage>(sub: &mut courier::Subscriber<M>) -> Res<M> {
    match tokio::time::timeout(T, sub.next()).await {
        Ok(Some(s)) => Ok(s?.value),
        Ok(None) => Err("subscription ended".into()),
        Err(_) => Err(format!("no sample within {T:?}").into()),
    }
}

/// Publishes `seq` 1000+ until the reader gets one: DDS discovery inside
/// the agent takes a while, and volatile samples before it are lost.
async fn matched(p: &courier::Publisher<Msg>, sub: &mut courier::Subscriber<Msg>) -> Res<()> {
    let start = Instant::now();
    for i in 0.. {
        p.publish(&msg(1000 + i, 4)).await?;
        if let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(200), sub.next()).await {
            println!("  matched after {:?}", start.elapsed());
            // take what else was in flight
            while let Ok(Some(_)) =
                tokio::time::timeout(Duration::from_millis(300), sub.next()).await
            {}
            return Ok(());
        }
        if start.elapsed() > Duration::from_secs(15) {
            break;
        }
    }
    Err("writer and reader never matched".into())
}

async fn stream_of(
    p: &courier::Publisher<Msg>,
    sub: &mut courier::Subscriber<Msg>,
    what: &str,
    n: u32,
    len: usize,
    confirmed: bool,
) -> Res<()> {
    let t = Instant::now();
    for i in 0..n {
        if confirmed {
            p.publish(&msg(i, len)).confirmed().await?;
        } else {
            p.publish(&msg(i, len)).await?;
        }
    }
    let mut got = Vec::new();
    while got.len() < n as usize {
        match next(sub).await {
            Ok(m) if m.seq < n => {
                if m != msg(m.seq, len) {
                    return Err(format!("sample {} corrupted", m.seq).into());
                }
                got.push(m.seq);
            }
            Ok(_) => {}
            Err(e) => {
                println!("  {what}: {} of {n} arrived ({e})", got.len());
                return Ok(());
            }
        }
    }
    let in_order = got.windows(2).all(|w| w[0] < w[1]);
    println!(
        "  {what}: {n} x {len} B arrived{} in {:?}",
        if in_order {
            " in order"
        } else {
            " OUT OF ORDER"
        },
        t.elapsed()
    );
    Ok(())
}

pub async fn pubsub(url: &str, two: bool) -> Res<()> {
    let a = Session::builder(url).name("check-a").connect().await?;
    let b = if two {
        Session::builder(url).name("check-b").connect().await?
    } else {
        a.clone()
    };
    println!("  sessions created");
    let mut sub = b.subscribe::<Msg>("check_reliable").await?;
    let p = a.publisher::<Msg>("check_reliable").build().await?;
    matched(&p, &mut sub).await?;
    stream_of(&p, &mut sub, "reliable", 100, 16, false).await?;
    stream_of(&p, &mut sub, "reliable confirmed", 10, 16, true).await?;
    stream_of(&p, &mut sub, "reliable 20000-byte", 3, 20_000, true).await?;
    let mut qs = SubscriptionQos::default();
    qs.reliability = Reliability::BestEffort;
    let mut be_sub = b.subscriber::<Msg>("check_be").qos(qs).build().await?;
    let mut qp = PublicationQos::default();
    qp.reliability = Reliability::BestEffort;
    let be = a.publisher::<Msg>("check_be").qos(qp).build().await?;
    matched(&be, &mut be_sub).await?;
    stream_of(&be, &mut be_sub, "best effort", 100, 16, false).await?;
    match be.publish(&msg(0, 20_000)).await {
        Ok(()) => println!("  best effort 20000-byte: accepted (!)"),
        Err(e) => println!("  best effort 20000-byte refused: {e}"),
    }
    a.close().await;
    b.close().await;
    Ok(())
}

async fn by_reference(url: &str) -> Res<()> {
    let sep = if url.contains('?') { '&' } else { '?' };
    let url = format!(
        "{url}{sep}representation=reference&ref.topic.Square=shapetype_topic\
         &ref.data_writer.Square=shapetype_data_writer&ref.data_reader.Square=shapetype_data_reader"
    );
    let s = Session::builder(url).name("check-ref").connect().await?;
    let mut sub = s.subscribe::<ShapeType>("Square").await?;
    let p = s.publisher::<ShapeType>("Square").build().await?;
    println!("  participant, topic, writer, reader created by reference");
    let shape = |x| ShapeType {
        color: "RED".into(),
        x,
        y: 2 * x,
        shapesize: 30,
    };
    for x in 0..20 {
        p.publish(&shape(x)).confirmed().await?;
        if let Ok(Some(Ok(got))) =
            tokio::time::timeout(Duration::from_millis(300), sub.next()).await
        {
            println!("  read back {:?}", got.value);
            return Ok(());
        }
    }
    Err("nothing read back".into())
}

pub async fn rpc(url: &str, two: bool) -> Res<()> {
    let server = Session::builder(url).name("check-server").connect().await?;
    let client = if two {
        Session::builder(url).name("check-client").connect().await?
    } else {
        server.clone()
    };
    let mut reqs = server.serve::<AddRequest, AddReply>("add", "").await?;
    tokio::spawn(async move {
        while let Some(Ok(r)) = reqs.next().await {
            let sum = r.value.a + r.value.b;
            let _ = r.reply(&AddReply { sum }).await;
        }
    });
    println!("  replier and requester created");
    let start = Instant::now();
    let mut ok = 0;
    for i in 0..40 {
        match client
            .query::<_, AddReply>("add", &AddRequest { a: i, b: 1 })
            .timeout(Duration::from_millis(500))
            .await
        {
            Ok(r) if r.sum == i + 1 => ok += 1,
            Ok(r) => return Err(format!("{i} + 1 = {}?", r.sum).into()),
            Err(e) if ok == 0 => println!("  query {i}: {e} (matching)"),
            Err(e) => return Err(e.into()),
        }
        if ok >= 10 {
            println!("  10 replies right, first after {:?}", start.elapsed());
            return Ok(());
        }
    }
    Err("no replies".into())
}

async fn ping(url: &str) -> Res<()> {
    let s = Session::builder(url).name("check-ping").connect().await?;
    let x = s.xrce()?;
    for _ in 0..3 {
        println!("  ping: {:?}", x.ping(T).await?);
    }
    let t = x.sync_time(T).await?;
    println!("  time sync: offset {} ns, rtt {:?}", t.offset_ns, t.rtt);
    println!("  agent time now: {:?}", x.agent_time());
    s.close().await;
    Ok(())
}

async fn watch(url: &str, secs: u64) -> Res<()> {
    let a = Session::builder(url).name("watch-a").connect().await?;
    let b = Session::builder(url).name("watch-b").connect().await?;
    let mut ev = a.events();
    let mut evb = b.events();
    // transient-local: samples the agent takes before the reader's DDS
    // endpoint is matched again (after a restart) still reach it
    let mut qs = SubscriptionQos::default();
    qs.durability = courier::Durability::TransientLocal;
    qs.history = courier::History::KeepLast(1000);
    let mut sub = b.subscriber::<Msg>("watch").qos(qs).build().await?;
    let mut qp = PublicationQos::default();
    qp.durability = courier::Durability::TransientLocal;
    qp.history = courier::History::KeepLast(1000);
    let p = a.publisher::<Msg>("watch").qos(qp).build().await?;
    let end = Instant::now() + Duration::from_secs(secs);
    let mut tick = a.every(Duration::from_millis(100));
    let start = Instant::now();
    let mut seq = 0;
    let mut got = std::collections::BTreeSet::new();
    while Instant::now() < end {
        tokio::select! {
            _ = tick.next() => {
                match p.publish(&msg(seq, 8)).await {
                    Ok(()) => seq += 1,
                    Err(e) => println!("  {:>6.1}s publish {seq}: {e}", start.elapsed().as_secs_f64()),
                }
            }
            Some(e) = ev.next() => println!("  {:>6.1}s a: {e:?}", start.elapsed().as_secs_f64()),
            Some(e) = evb.next() => println!("  {:>6.1}s b: {e:?}", start.elapsed().as_secs_f64()),
            Some(s) = sub.next() => { if let Ok(s) = s { got.insert(s.value.seq); } }
        }
    }
    let missing: Vec<u32> = (0..seq).filter(|s| !got.contains(s)).collect();
    println!(
        "  published {seq}, read {} distinct; missing {:?}",
        got.len(),
        missing
    );
    Ok(())
}

#[tokio::main]
async fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (Some(url), Some(step)) = (args.get(1), args.get(2)) else {
        eprintln!("usage: xrce_check <url> pubsub|self|ref|rpc|rpc1|ping|watch [seconds]");
        std::process::exit(2);
    };
    let secs = match args.get(3).map(|s| s.parse()) {
        None => 20,
        Some(Ok(s)) => s,
        Some(Err(_)) => {
            eprintln!("xrce_check: {:?} is not a number of seconds", args[3]);
            std::process::exit(2);
        }
    };
    println!("{step} on {url}");
    let r = match step.as_str() {
        "pubsub" => pubsub(url, true).await,
        "self" => pubsub(url, false).await,
        "ref" => by_reference(url).await,
        "rpc" => rpc(url, true).await,
        "rpc1" => rpc(url, false).await,
        "ping" => ping(url).await,
        "watch" => watch(url, secs).await,
        s => Err(format!("unknown step {s}").into()),
    };
    match r {
        Ok(()) => println!("{step}: done"),
        Err(e) => {
            println!("{step}: FAILED: {e}");
            std::process::exit(1);
        }
    }
}
