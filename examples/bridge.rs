//! A bridge between two centrals (the IPC manual §7's use of contexts): one
//! `Session` per central; every message named on the command line that is
//! published on the first central is republished, byte for byte, on the
//! second.
//!
//! ```text
//! cargo run -p courier-examples --bin bridge -- ipc://hostA:1381 ipc://hostB:1381 message1:int message2:string
//! ```
//! Each message is given as `name:format` (its IPC format string), so the
//! bridge can define it on the second central.

use courier::Session;

/// Forwards `msgs` (name, format) from `from` to `to` until `from` ends.
async fn bridge(
    from: &Session,
    to: &Session,
    msgs: &[(String, String)],
) -> Result<(), courier::Error> {
    let mut tasks = Vec::new();
    for (name, fmt) in msgs {
        let fmt = (!fmt.is_empty()).then_some(fmt.as_str());
        from.ipc()?.define(name, fmt).await?;
        to.ipc()?.define(name, fmt).await?;
        let mut rx = from.subscribe_raw(name).await?;
        let to = to.clone();
        let name = name.clone();
        tasks.push(tokio::spawn(async move {
            // None: the first central went away
            while let Some(s) = rx.recv().await {
                if let Err(e) = to.publish_raw(&name, &s.data).await {
                    eprintln!("bridge: {name}: {e}");
                    break;
                }
            }
        }));
    }
    for t in tasks {
        let _ = t.await;
    }
    Ok(())
}

#[tokio::main(flavor = "current_thread")]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!("usage: bridge <from-url> <to-url> name:format...");
        std::process::exit(2);
    }
    let mut msgs = Vec::new();
    for m in &args[2..] {
        match m.split_once(':') {
            Some((n, f)) if !n.is_empty() => msgs.push((n.to_string(), f.to_string())),
            _ => {
                eprintln!("bridge: '{m}' is not name:format");
                std::process::exit(2);
            }
        }
    }
    let from = Session::builder(&args[0])
        .name("bridge-in")
        .connect()
        .await?;
    let to = Session::builder(&args[1])
        .name("bridge-out")
        .connect()
        .await?;
    println!(
        "bridge: {} -> {} for {} message(s)",
        args[0],
        args[1],
        msgs.len()
    );
    bridge(&from, &to, &msgs).await?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use courier::Session;
    use courier_broker::CentralServer;
    use futures::StreamExt;

    #[tokio::test]
    async fn messages_cross_from_one_central_to_the_other() {
        let t = Duration::from_secs(20);
        let a = CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(0)
            .spawn()
            .await
            .unwrap();
        let b = CentralServer::builder()
            .bind([127, 0, 0, 1].into())
            .port(0)
            .spawn()
            .await
            .unwrap();
        let (ua, ub) = (
            format!("ipc://{}", a.local_addr()),
            format!("ipc://{}", b.local_addr()),
        );
        let from = Session::builder(&ua)
            .name("bridge-in")
            .connect()
            .await
            .unwrap();
        let to = Session::builder(&ub)
            .name("bridge-out")
            .connect()
            .await
            .unwrap();
        let msgs = vec![("message1".to_string(), "int".to_string())];
        let listener = Session::builder(&ub)
            .name("listener")
            .connect()
            .await
            .unwrap();
        let mut sub = listener.subscribe::<i32>("message1").await.unwrap();
        listener.num_handlers("message1").await.unwrap();
        let (f2, t2) = (from.clone(), to.clone());
        let bridge = tokio::spawn(async move { super::bridge(&f2, &t2, &msgs).await });
        let publisher = Session::builder(&ua)
            .name("publisher")
            .connect()
            .await
            .unwrap();
        // Publish until the bridge's subscription is known on central A and
        // the listener's on central B reaches the bridge.
        let deadline = tokio::time::Instant::now() + t;
        let v = loop {
            publisher.publish("message1", &42i32).await.unwrap();
            if let Ok(Some(s)) = tokio::time::timeout(Duration::from_millis(200), sub.next()).await
            {
                break s.unwrap().value;
            }
            assert!(
                tokio::time::Instant::now() < deadline,
                "nothing crossed the bridge"
            );
        };
        assert_eq!(v, 42);
        a.shutdown().await;
        let _ = tokio::time::timeout(t, bridge).await;
        b.shutdown().await;
    }
}
